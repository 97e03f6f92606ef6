//! Pairing observations of cameras that are not hardware-synchronised into frame sets.
//!
//! Each camera's observations queue in arrival order. The oldest waiting observation is the
//! reference; every other *live* camera contributes its observation closest in time to it,
//! if within `max_skew`. A set is released as soon as every live camera has contributed, or
//! when waiting longer cannot help: each missing camera has already sent something later than
//! the reference window (it missed this frame) or is overdue — later than its usual delay
//! from exposure to arrival here, plus six times that delay's usual deviation and 3 ms (each
//! camera's arrival is learnt from its observations) — or the reference has waited
//! `max_wait`. So a
//! missing or late frame costs at most `max_wait` of latency, and a set then holds fewer
//! cameras. A camera silent for `camera_timeout` is not live (not waited for) until it is
//! heard again; its stale observations are discarded. Right after start, a camera not heard
//! yet counts as live for `camera_timeout` (from the first observation of any camera), so
//! the first sets wait for cameras that start a little later instead of going out alone.
//!
//! *Replay.* Given the sets a recording made ([`Pairer::with_schedule`]: each recorded pose
//! frame's time and cameras), a set is formed with exactly the cameras the recorded one had
//! and released as soon as they are all in — however the frames arrive on the replaying
//! machine. A set the recording does not have pairs as above.
//!
//! Sets go out in time order, each at most once: an observation that arrives after its set was
//! released without it (its camera was late by more than `max_wait`), or that is older than
//! the last set released, is discarded and counted as late — it would otherwise go out as a
//! second, one-camera pose frame for a time already published, after newer ones.

use std::collections::{BTreeMap, VecDeque};
use stereoscope_proto::messages::Observation;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairingConfig {
    pub max_skew_ns: u64,
    pub max_wait_ns: u64,
    pub camera_timeout_ns: u64,
    /// An observation stamped more than this ahead of the receiver's clock is refused
    /// (one from the future would hold every later set back as "late").
    pub max_ahead_ns: u64,
    /// An observation stamped more than this behind the receiver's clock is refused; `None`
    /// for a replay, whose frames keep their recorded times.
    pub max_behind_ns: Option<u64>,
}

/// Why [`Pairer::push`] refused an observation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Refused {
    #[error(
        "stamped {ahead_ms} ms ahead of this PC's clock (more than {limit_ms} ms): is its PC's clock synchronised with this one's (chrony, PTP)?"
    )]
    Future { ahead_ms: u64, limit_ms: u64 },
    #[error(
        "stamped {behind_ms} ms behind this PC's clock (more than {limit_ms} ms): is its PC's clock synchronised with this one's (chrony, PTP), or is it replaying old times?"
    )]
    Stale { behind_ms: u64, limit_ms: u64 },
}

impl Refused {
    /// A short name for counting refusals by reason.
    pub fn reason(&self) -> &'static str {
        match self {
            Refused::Future { .. } => "future",
            Refused::Stale { .. } => "stale",
        }
    }
}

#[derive(Debug)]
struct Queue {
    items: VecDeque<(Observation, u64)>,
    last_arrival_ns: Option<u64>,
    arrival: Arrival,
}

/// Observations a camera must have delivered before its arrival is predicted.
const ARRIVAL_WARMUP: u32 = 8;
/// Slack over a camera's predicted arrival before a set stops waiting for it. (With 1 ms and
/// four deviations, about 1 % of the demo's sets went out a camera short whose observation
/// then came: synthetic cameras render on the same two cores; with 3 ms and six, none in 3
/// runs of 6 s.)
const ARRIVAL_MARGIN_NS: f64 = 3_000_000.0;

/// How late a camera's observations arrive after their exposure (exponential averages of the
/// lag and of its deviation, weight 1/8): its observation for an exposure is due by
/// `timestamp + lag + 6 · deviation + 3 ms`.
#[derive(Debug, Default, Clone, Copy)]
struct Arrival {
    samples: u32,
    lag_ns: f64,
    deviation_ns: f64,
}

impl Arrival {
    fn note(&mut self, timestamp_ns: u64, now_ns: u64) {
        let lag = now_ns as f64 - timestamp_ns as f64;
        if self.samples == 0 {
            self.lag_ns = lag;
        } else {
            let d = lag - self.lag_ns;
            self.lag_ns += d / 8.0;
            self.deviation_ns += (d.abs() - self.deviation_ns) / 8.0;
        }
        self.samples = self.samples.saturating_add(1);
    }

    /// When this camera's observation of exposure `timestamp_ns` is due at the latest, once
    /// enough have been seen to tell.
    fn due_ns(&self, timestamp_ns: u64) -> Option<u64> {
        (self.samples >= ARRIVAL_WARMUP).then(|| {
            let wait = (self.lag_ns + 6.0 * self.deviation_ns + ARRIVAL_MARGIN_NS).max(0.0);
            timestamp_ns.saturating_add(wait as u64)
        })
    }
}

/// Observations of `n` cameras, paired into sets.
#[derive(Debug)]
pub struct Pairer {
    cfg: PairingConfig,
    queues: Vec<Queue>,
    /// Observations thrown away unpaired (too old, superseded, or late).
    pub discarded: u64,
    /// Of those, observations that came after their set had gone out without them.
    pub late: u64,
    /// A starting camera's first observations that came after their set had gone out (the
    /// set did not wait for a camera not yet heard from): thrown away, not counted as lost.
    pub before_start: u64,
    /// The last released set: its reference time, the cameras in it, and the cameras it
    /// could wait for (live then; not one still starting).
    released: Option<(u64, Vec<bool>, Vec<bool>)>,
    /// When the first observation of any camera arrived.
    first_arrival_ns: Option<u64>,
    /// Recorded sets not formed yet: reference time → the cameras in it.
    schedule: BTreeMap<u64, Vec<bool>>,
    /// A schedule was given (replay).
    scheduled: bool,
    /// Recorded sets released without one of their cameras (its frame was lost on the way).
    pub short_sets: u64,
    /// The last observation discarded as late or superseded: camera and frame sequence.
    pub last_lost: Option<(usize, u64)>,
}

const MAX_QUEUE: usize = 16;

/// Why a recording's pose frames do not give a schedule.
#[derive(Debug, thiserror::Error)]
pub enum ScheduleError {
    #[error("{}", .file.display())]
    Read {
        file: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}:{line}: not a pose frame", .file.display())]
    Line {
        file: std::path::PathBuf,
        line: usize,
        #[source]
        source: stereoscope_proto::messages::DecodeError,
    },
}

/// The sets a recording formed, from its `poses.jsonl`: each pose frame's time and which of
/// `cameras` it had (a camera the rig does not have is ignored). An incomplete last line (a
/// recorder stopped mid-write) is skipped, as the session reader does.
pub fn read_schedule(
    file: &std::path::Path,
    cameras: &[String],
) -> Result<BTreeMap<u64, Vec<bool>>, ScheduleError> {
    use std::io::BufRead;
    use stereoscope_proto::messages::{Message, PoseFrame};
    let read = |source| ScheduleError::Read {
        file: file.to_path_buf(),
        source,
    };
    let reader = std::io::BufReader::new(std::fs::File::open(file).map_err(read)?);
    let mut schedule = BTreeMap::new();
    let mut pending: Option<ScheduleError> = None;
    for (i, line) in reader.split(b'\n').enumerate() {
        let line = line.map_err(read)?;
        if line.is_empty() {
            continue;
        }
        // Only the last line may be cut short.
        if let Some(e) = pending.take() {
            return Err(e);
        }
        match PoseFrame::from_json(&line) {
            Ok(f) => {
                let had = cameras.iter().map(|c| f.cameras.contains(c)).collect();
                schedule.insert(f.timestamp_ns, had);
            }
            Err(source) => {
                pending = Some(ScheduleError::Line {
                    file: file.to_path_buf(),
                    line: i + 1,
                    source,
                })
            }
        }
    }
    Ok(schedule)
}

impl Pairer {
    pub fn new(cameras: usize, cfg: PairingConfig) -> Self {
        Pairer {
            cfg,
            queues: (0..cameras)
                .map(|_| Queue {
                    items: VecDeque::new(),
                    last_arrival_ns: None,
                    arrival: Arrival::default(),
                })
                .collect(),
            discarded: 0,
            late: 0,
            released: None,
            before_start: 0,
            first_arrival_ns: None,
            schedule: BTreeMap::new(),
            scheduled: false,
            short_sets: 0,
            last_lost: None,
        }
    }

    /// Forms the sets a recording made: `schedule` maps each recorded set's time (its oldest
    /// observation's `timestamp_ns`) to the cameras it had (`n` flags each).
    pub fn with_schedule(mut self, schedule: BTreeMap<u64, Vec<bool>>) -> Self {
        self.schedule = schedule;
        self.scheduled = true;
        self
    }

    /// With a schedule: every recorded set has been formed (or passed, its frames lost).
    pub fn schedule_done(&self) -> bool {
        self.scheduled && self.schedule.is_empty()
    }

    fn lose(&mut self, camera: usize, obs: &Observation) {
        self.discarded += 1;
        self.last_lost = Some((camera, obs.sequence));
    }

    /// Adds camera `camera`'s observation, arrived at `now_ns`, unless its time is outside
    /// the clock window (then nothing changes).
    pub fn push(&mut self, camera: usize, obs: Observation, now_ns: u64) -> Result<(), Refused> {
        let ms = |ns: u64| ns / 1_000_000;
        let ahead = obs.timestamp_ns.saturating_sub(now_ns);
        if ahead > self.cfg.max_ahead_ns {
            return Err(Refused::Future {
                ahead_ms: ms(ahead),
                limit_ms: ms(self.cfg.max_ahead_ns),
            });
        }
        let behind = now_ns.saturating_sub(obs.timestamp_ns);
        if let Some(limit) = self.cfg.max_behind_ns
            && behind > limit
        {
            return Err(Refused::Stale {
                behind_ms: ms(behind),
                limit_ms: ms(limit),
            });
        }
        let Some(q) = self.queues.get_mut(camera) else {
            return Ok(());
        };
        let obs_timestamp_ns = obs.timestamp_ns;
        // Out of order (older than what is queued) is kept in order.
        let pos = q
            .items
            .iter()
            .position(|(o, _)| o.timestamp_ns > obs.timestamp_ns)
            .unwrap_or(q.items.len());
        q.items.insert(pos, (obs, now_ns));
        self.first_arrival_ns.get_or_insert(now_ns);
        q.last_arrival_ns = Some(now_ns);
        q.arrival.note(obs_timestamp_ns, now_ns);
        while q.items.len() > MAX_QUEUE {
            if let Some((o, _)) = q.items.pop_front() {
                self.discarded += 1;
                self.last_lost = Some((camera, o.sequence));
            }
        }
        Ok(())
    }

    /// Whether camera `c` counts as live at `now_ns`: it delivered within the camera
    /// timeout, or it has delivered nothing yet and the first observation of any camera came
    /// less than `max_wait` ago (cameras started together pair from their first frame). A
    /// camera still starting after that is not waited for: waiting the full `max_wait` for it
    /// made every set late until it started (a 25 ms tail on the first 0.1–0.5 s of a run at
    /// 120 fps, performance.md).
    pub fn live(&self, c: usize, now_ns: u64) -> bool {
        match self.queues[c].last_arrival_ns {
            Some(t) => now_ns.saturating_sub(t) <= self.cfg.camera_timeout_ns,
            None => self
                .first_arrival_ns
                .is_some_and(|t| now_ns.saturating_sub(t) <= self.cfg.max_wait_ns),
        }
    }

    /// The next complete (or given-up-on) set: `(camera, observation)` pairs.
    pub fn pop(&mut self, now_ns: u64) -> Option<Vec<(usize, Observation)>> {
        let n = self.queues.len();
        // Drop what dead cameras left.
        for c in 0..n {
            if !self.live(c, now_ns) && !self.queues[c].items.is_empty() {
                self.discarded += self.queues[c].items.len() as u64;
                if let Some((o, _)) = self.queues[c].items.back() {
                    self.last_lost = Some((c, o.sequence));
                }
                self.queues[c].items.clear();
            }
        }
        // Drop what came too late for a set already released: anything not newer than it, and
        // a missing camera's observation within its window.
        if let Some((t, ref cameras, ref awaited)) = self.released {
            let skew = self.cfg.max_skew_ns;
            for (c, q) in self.queues.iter_mut().enumerate() {
                let limit = if cameras[c] {
                    t
                } else {
                    t.saturating_add(skew)
                };
                while q
                    .items
                    .front()
                    .is_some_and(|(o, _)| o.timestamp_ns <= limit)
                {
                    if let Some((o, _)) = q.items.pop_front() {
                        // A camera's first frames, from before it was live, were never waited
                        // for: not a loss.
                        if cameras[c] || awaited[c] {
                            self.discarded += 1;
                            self.late += 1;
                            self.last_lost = Some((c, o.sequence));
                        } else {
                            self.before_start += 1;
                        }
                    }
                }
            }
        }
        let (ref_cam, ref_ts, ref_arrival) = loop {
            let (c, ts, arrival) = (0..n)
                .filter_map(|c| {
                    self.queues[c]
                        .items
                        .front()
                        .map(|(o, a)| (c, o.timestamp_ns, *a))
                })
                .min_by_key(|x| x.1)?;
            // A camera the recorded set at this time did not have: the recording lost this
            // observation (it came too late), so the replay does too.
            if self.schedule.get(&ts).is_some_and(|cams| !cams[c])
                && let Some((o, _)) = self.queues[c].items.pop_front()
            {
                self.lose(c, &o);
                self.late += 1;
                continue;
            }
            break (c, ts, arrival);
        };
        // Recorded sets older than this one are past.
        while self
            .schedule
            .first_key_value()
            .is_some_and(|(t, _)| *t < ref_ts)
        {
            self.schedule.pop_first();
        }
        let recorded = self.schedule.get(&ref_ts).cloned();
        let skew = self.cfg.max_skew_ns;
        let mut chosen: Vec<Option<usize>> = vec![None; n];
        let mut complete = true;
        // Every missing camera given up on: it moved past this set, or (live only) its
        // observation is overdue by its own arrival record.
        let mut all_gone = true;
        for c in 0..n {
            if c == ref_cam {
                chosen[c] = Some(0);
                continue;
            }
            match &recorded {
                // Exactly the recorded set's cameras, each waited for.
                Some(cams) if !cams[c] => continue,
                Some(_) => {}
                None if !self.live(c, now_ns) => continue,
                None => {}
            }
            let q = &self.queues[c].items;
            let best = q
                .iter()
                .enumerate()
                .filter(|(_, (o, _))| o.timestamp_ns.abs_diff(ref_ts) <= skew)
                .min_by_key(|(_, (o, _))| o.timestamp_ns.abs_diff(ref_ts));
            match best {
                Some((i, _)) => chosen[c] = Some(i),
                None => {
                    complete = false;
                    let moved_past = q
                        .back()
                        .is_some_and(|(o, _)| o.timestamp_ns > ref_ts + skew);
                    let overdue = recorded.is_none()
                        && self.queues[c]
                            .arrival
                            .due_ns(ref_ts)
                            .is_some_and(|due| now_ns > due);
                    if !(moved_past || overdue) {
                        all_gone = false;
                    }
                }
            }
        }
        let waited = now_ns.saturating_sub(ref_arrival);
        if !complete && !all_gone && waited < self.cfg.max_wait_ns {
            return None;
        }
        if recorded.is_some() {
            self.schedule.remove(&ref_ts);
            if !complete {
                self.short_sets += 1;
            }
        }
        let mut set = Vec::new();
        let awaited = (0..n).map(|c| self.live(c, now_ns)).collect();
        self.released = Some((
            ref_ts,
            chosen.iter().map(Option::is_some).collect(),
            awaited,
        ));
        for c in 0..n {
            let q = &mut self.queues[c].items;
            if let Some(i) = chosen[c] {
                // Everything older than the chosen one is superseded.
                for (o, _) in q.drain(..i) {
                    self.discarded += 1;
                    self.last_lost = Some((c, o.sequence));
                }
                if let Some((o, _)) = q.pop_front() {
                    set.push((c, o));
                }
            } else {
                // Drop this camera's entries at or before the reference window.
                while q
                    .front()
                    .is_some_and(|(o, _)| o.timestamp_ns + skew < ref_ts)
                {
                    if let Some((o, _)) = q.pop_front() {
                        self.discarded += 1;
                        self.last_lost = Some((c, o.sequence));
                    }
                }
            }
        }
        Some(set)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::SCHEMA_VERSION;

    fn obs(cam: &str, ts_ms: u64) -> Observation {
        Observation {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            camera: cam.into(),
            sequence: ts_ms,
            timestamp_ns: ts_ms * 1_000_000,
            frame_published_ns: 0,
            published_ns: 0,
            width_px: 1,
            height_px: 1,
            threshold: 1,
            dark: false,
            full_frame: false,
            dropped_blobs: 0,
            blobs: vec![],
        }
    }

    const MS: u64 = 1_000_000;

    fn cfg() -> PairingConfig {
        PairingConfig {
            max_skew_ns: 5 * MS,
            max_wait_ns: 20 * MS,
            camera_timeout_ns: 500 * MS,
            max_ahead_ns: 1000 * MS,
            max_behind_ns: None,
        }
    }

    #[test]
    fn pairs_within_skew_and_waits_for_live_cameras() {
        let mut p = Pairer::new(2, cfg());
        p.push(0, obs("a", 100), 101 * MS).unwrap();
        p.push(1, obs("b", 90), 91 * MS).unwrap();
        // cam1's 90 ms frame is alone (cam0 has nothing near it, but cam0 is already past).
        let s = p.pop(101 * MS).unwrap();
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].0, 1);
        // cam0's 100 waits for cam1 (live) until it comes.
        assert!(p.pop(102 * MS).is_none());
        p.push(1, obs("b", 102), 103 * MS).unwrap();
        let s = p.pop(103 * MS).unwrap();
        assert_eq!(s.iter().map(|x| x.0).collect::<Vec<_>>(), vec![0, 1]);
        assert!(p.pop(103 * MS).is_none());
    }

    /// A camera later than `max_wait`: its set goes out without it, and its observation, when
    /// it comes, is dropped as late — never a second set for that time, after newer ones.
    #[test]
    fn a_late_observation_never_makes_a_second_set_for_its_time() {
        let mut p = Pairer::new(2, cfg());
        p.push(0, obs("a", 100), 101 * MS).unwrap();
        p.push(1, obs("b", 100), 101 * MS).unwrap();
        assert_eq!(p.pop(101 * MS).unwrap().len(), 2);
        // Frame 133: cam1 is late, cam0's goes out alone after max_wait.
        p.push(0, obs("a", 133), 134 * MS).unwrap();
        assert!(p.pop(140 * MS).is_none());
        let s = p.pop(155 * MS).unwrap();
        assert_eq!(s.iter().map(|x| x.0).collect::<Vec<_>>(), vec![0]);
        // Frame 166 of both, and cam1's 133 (1 ms off its clock) arriving after it.
        p.push(0, obs("a", 166), 167 * MS).unwrap();
        p.push(1, obs("b", 166), 167 * MS).unwrap();
        p.push(1, obs("b", 134), 168 * MS).unwrap();
        let s = p.pop(168 * MS).unwrap();
        assert_eq!(s.len(), 2);
        assert!(s.iter().all(|(_, o)| o.timestamp_ns == 166 * MS), "{s:?}");
        assert!(p.pop(200 * MS).is_none());
        assert_eq!((p.late, p.discarded), (1, 1));
        // Sets keep coming: the next frame pairs as usual.
        p.push(0, obs("a", 200), 201 * MS).unwrap();
        p.push(1, obs("b", 200), 201 * MS).unwrap();
        assert_eq!(p.pop(201 * MS).unwrap().len(), 2);
    }

    #[test]
    fn gives_up_after_max_wait_and_forgets_dead_cameras() {
        let mut p = Pairer::new(2, cfg());
        p.push(1, obs("b", 0), 0).unwrap();
        // Just started: cam0, not heard yet, is waited for (up to max_wait).
        assert!(p.pop(0).is_none());
        assert_eq!(p.pop(21 * MS).unwrap().len(), 1);
        // A camera not heard from by then is still starting: later sets do not wait for it.
        let mut q = Pairer::new(2, cfg());
        q.push(1, obs("b", 0), 0).unwrap();
        assert_eq!(q.pop(21 * MS).unwrap().len(), 1);
        q.push(1, obs("b", 33), 33 * MS).unwrap();
        assert_eq!(q.pop(33 * MS).unwrap().len(), 1);
        assert!(!q.live(0, 33 * MS));
        // Its first frame, when it comes after its set left, is dropped but is not a loss.
        q.push(0, obs("a", 33), 40 * MS).unwrap();
        q.push(1, obs("b", 66), 66 * MS).unwrap();
        q.push(0, obs("a", 66), 66 * MS).unwrap();
        assert_eq!(q.pop(66 * MS).unwrap().len(), 2);
        assert_eq!((q.late, q.discarded, q.before_start), (0, 0, 1));
        p.push(0, obs("a", 10), 10 * MS).unwrap();
        assert!(p.pop(15 * MS).is_none());
        let s = p.pop(31 * MS).unwrap();
        assert_eq!(s.len(), 1);
        // After the timeout cam1 is not waited for at all.
        p.push(0, obs("a", 600), 600 * MS).unwrap();
        assert_eq!(p.pop(600 * MS).unwrap().len(), 1);
        assert!(!p.live(1, 600 * MS));
        // It comes back.
        p.push(1, obs("b", 633), 634 * MS).unwrap();
        p.push(0, obs("a", 633), 634 * MS).unwrap();
        assert_eq!(p.pop(634 * MS).unwrap().len(), 2);
    }

    /// Given the recorded sets, a replay forms the same ones whatever the arrival: a set waits
    /// for each camera the recorded one had (up to `max_wait`, a camera not heard for long
    /// included), leaves out one it did not have, and goes out as soon as it is complete.
    #[test]
    fn a_schedule_forms_the_recorded_sets_whatever_the_arrival() {
        let schedule = BTreeMap::from([
            (0, vec![true, true]),
            (700 * MS, vec![true, true]),
            (733 * MS, vec![true, false]),
            (766 * MS, vec![true, true]),
        ]);
        let mut p = Pairer::new(2, cfg()).with_schedule(schedule);
        assert!(!p.schedule_done());
        p.push(0, obs("a", 0), 0).unwrap();
        p.push(1, obs("b", 0), 0).unwrap();
        assert_eq!(p.pop(0).unwrap().len(), 2);
        // cam1, silent for longer than the camera timeout, is still waited for.
        p.push(0, obs("a", 700), 700 * MS).unwrap();
        assert!(!p.live(1, 705 * MS));
        assert!(p.pop(705 * MS).is_none());
        p.push(1, obs("b", 700), 710 * MS).unwrap();
        let s = p.pop(710 * MS).unwrap();
        assert_eq!(s.iter().map(|x| x.0).collect::<Vec<_>>(), vec![0, 1]);
        // Frame 733 was recorded without cam1: its observation, here on time, is left out
        // and the set goes out at once.
        p.push(1, obs("b", 733), 734 * MS).unwrap();
        p.push(0, obs("a", 733), 734 * MS).unwrap();
        let s = p.pop(734 * MS).unwrap();
        assert_eq!(s.iter().map(|x| x.0).collect::<Vec<_>>(), vec![0]);
        // Frame 766: cam1's frame never comes (lost in the replay) — after max_wait the set
        // goes out short, and is counted.
        p.push(0, obs("a", 766), 767 * MS).unwrap();
        assert!(p.pop(780 * MS).is_none());
        assert_eq!(p.late, 1);
        assert_eq!(p.last_lost, Some((1, 733)));
        let s = p.pop(790 * MS).unwrap();
        assert_eq!(s.len(), 1);
        assert_eq!(p.short_sets, 1);
        assert!(p.schedule_done());
        // A time the recording does not have pairs as live.
        p.push(0, obs("a", 800), 801 * MS).unwrap();
        p.push(1, obs("b", 800), 801 * MS).unwrap();
        assert_eq!(p.pop(801 * MS).unwrap().len(), 2);
    }

    #[test]
    fn a_schedule_reads_from_a_recording_and_names_a_bad_line() {
        use stereoscope_proto::messages::{Message, PoseFrame};
        let frame = |ts_ms: u64, cameras: &[&str]| {
            let f = PoseFrame {
                schema: SCHEMA_VERSION,
                rig: "r".into(),
                sequence: ts_ms,
                timestamp_ns: ts_ms * MS,
                frame_published_ns: 0,
                published_ns: 0,
                cameras: cameras.iter().map(|c| c.to_string()).collect(),
                poses: vec![],
                bodies: vec![],
                models: Vec::new(),
            };
            String::from_utf8(f.to_json()).unwrap()
        };
        let dir = std::env::temp_dir().join(format!("schedule-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("poses.jsonl");
        let ids = vec!["a".to_string(), "b".to_string()];
        // A last line cut short (a recorder stopped mid-write) is skipped.
        let text = format!(
            "{}\n{}\n{{\"schema\":1,",
            frame(0, &["a", "b"]),
            frame(33, &["b"])
        );
        std::fs::write(&file, text).unwrap();
        let s = read_schedule(&file, &ids).unwrap();
        assert_eq!(
            s,
            BTreeMap::from([(0, vec![true, true]), (33 * MS, vec![false, true])])
        );
        // One in the middle is an error naming the line.
        let text = format!("{}\nnot json\n{}\n", frame(0, &["a"]), frame(33, &["b"]));
        std::fs::write(&file, text).unwrap();
        let err = read_schedule(&file, &ids).unwrap_err();
        assert!(
            matches!(err, ScheduleError::Line { line: 2, .. }),
            "{err:?}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
        let err = read_schedule(&file, &ids).unwrap_err();
        assert!(matches!(err, ScheduleError::Read { .. }), "{err:?}");
    }

    /// One observation stamped an hour ahead (a forged or broken clock) is refused and changes
    /// nothing: the sets go on; with a limit behind, a stale one is refused too.
    #[test]
    fn observations_outside_the_clock_window_are_refused_and_change_nothing() {
        let now = 10_000 * MS;
        let mut p = Pairer::new(2, cfg());
        let hour = 3_600_000 * MS;
        let e = p.push(0, obs("a", 10_000 + 3_600_000), now).unwrap_err();
        assert_eq!(
            e,
            Refused::Future {
                ahead_ms: 3_600_000,
                limit_ms: 1000
            }
        );
        assert!(p.pop(now).is_none());
        p.push(0, obs("a", 10_000), now).unwrap();
        p.push(1, obs("b", 10_000), now).unwrap();
        assert_eq!(p.pop(now).unwrap().len(), 2);
        assert_eq!(p.late, 0);
        // A replay's recorded times are accepted however old; with a limit they are not.
        p.push(0, obs("a", 10_001), now + hour).unwrap();
        let mut strict = Pairer::new(
            2,
            PairingConfig {
                max_behind_ns: Some(1000 * MS),
                ..cfg()
            },
        );
        let e = strict.push(0, obs("a", 10_000), now + hour).unwrap_err();
        assert_eq!(e.reason(), "stale");
    }

    /// Once each camera's arrival is known (its observations come 2 ms after exposure, give or
    /// take 0.1 ms), a set missing one stops waiting when that camera is overdue — about 5.5 ms
    /// after the exposure — instead of the full `max_wait` (20 ms); the late observation, when
    /// it comes, is dropped as late. A camera whose record is not yet known is waited for as
    /// before.
    #[test]
    fn a_set_waits_for_a_camera_only_as_long_as_it_is_usually_late() {
        let mut p = Pairer::new(2, cfg());
        let period = 33 * MS;
        let mut t = 1000 * MS;
        // Before the record is known (fewer than 8 observations), a missing camera is waited
        // for up to max_wait.
        p.push(0, obs("a", t / MS), t + 2 * MS).unwrap();
        assert!(p.pop(t + 10 * MS).is_none());
        p.push(1, obs("b", t / MS), t + 2 * MS + 100_000).unwrap();
        assert_eq!(p.pop(t + 10 * MS).unwrap().len(), 2);
        for k in 0..10u64 {
            t += period;
            let jitter = (k % 3) * 100_000;
            p.push(0, obs("a", t / MS), t + 2 * MS + jitter).unwrap();
            p.push(1, obs("b", t / MS), t + 2 * MS + 100_000 - jitter)
                .unwrap();
            assert_eq!(p.pop(t + 3 * MS).unwrap().len(), 2);
        }
        // cam1's next observation is late.
        t += period;
        p.push(0, obs("a", t / MS), t + 2 * MS).unwrap();
        assert!(p.pop(t + 5 * MS).is_none(), "released before cam1 was due");
        let s = p.pop(t + 7 * MS).expect("released once cam1 was overdue");
        assert_eq!(s.iter().map(|x| x.0).collect::<Vec<_>>(), vec![0]);
        // It comes at last, and is dropped as late rather than making a second set.
        p.push(1, obs("b", t / MS), t + 15 * MS).unwrap();
        assert!(p.pop(t + 16 * MS).is_none());
        assert_eq!(p.late, 1);
    }
}
