//! A V4L2 frame's time and number: the driver's stamp moved to mid-exposure on the real-time
//! clock (the module's header, "Timestamps"), and its 32-bit sequence number continued past the
//! wrap.

/// How a frame's time is found (see the module's header).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Stamp {
    /// The driver's monotonic stamp; `+1` start of exposure, `-1` end of frame.
    Driver { start_of_exposure: bool },
    /// When the buffer was dequeued.
    Dequeue,
}

/// The real-time clock minus the monotonic one: of five readings of the pair, the one read
/// closest together (the least disturbed by a preemption between the two reads).
pub(super) fn clock_offset_ns() -> i128 {
    (0..5)
        .map(|_| {
            let m0 = clock_ns(libc::CLOCK_MONOTONIC);
            let r = clock_ns(libc::CLOCK_REALTIME);
            let m1 = clock_ns(libc::CLOCK_MONOTONIC);
            (m1 - m0, r - (m0 + m1) / 2)
        })
        .min_by_key(|&(spread, _)| spread)
        .map_or(0, |(_, offset)| offset)
}

pub(super) fn clock_ns(clock: libc::clockid_t) -> i128 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write.
    unsafe { libc::clock_gettime(clock, &mut ts) };
    ts.tv_sec as i128 * 1_000_000_000 + ts.tv_nsec as i128
}

/// A frame's mid-exposure on the real-time clock: the driver's stamp (`driver_ns`, monotonic)
/// moved by half the exposure towards its middle (and, from an end-of-frame stamp, back by the
/// readout first), then by the clocks' offset (`realtime_ns` and `monotonic_ns` read together).
pub(super) fn mid_exposure_ns(
    stamp: Stamp,
    driver_ns: i128,
    exposure_ns: Option<u64>,
    readout_ns: Option<u64>,
    realtime_ns: i128,
    monotonic_ns: i128,
) -> u64 {
    let ns = match stamp {
        Stamp::Dequeue => realtime_ns,
        Stamp::Driver { start_of_exposure } => {
            let half = exposure_ns.unwrap_or(0) as i128 / 2;
            let mid = if start_of_exposure {
                driver_ns + half
            } else {
                driver_ns - readout_ns.unwrap_or(0) as i128 - half
            };
            realtime_ns - (monotonic_ns - mid)
        }
    };
    ns.clamp(0, u64::MAX as i128) as u64
}

/// The driver's 32-bit sequence number, continued past its wrap.
#[derive(Debug, Default)]
pub(super) struct Sequence {
    last: Option<u32>,
    wraps: u64,
}

impl Sequence {
    pub(super) fn extend(&mut self, seq: u32) -> u64 {
        if let Some(last) = self.last
            && seq < last
            && last - seq > u32::MAX / 2
        {
            self.wraps += 1;
        }
        self.last = Some(seq);
        (self.wraps << 32) | seq as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_move_to_mid_exposure_on_the_real_time_clock() {
        // The clocks 1,000 s apart; the driver stamped 5 ms before the dequeue.
        let (real, mono) = (1_001_000_000_000i128, 1_000_000_000i128);
        let driver = mono - 5_000_000;
        let eof = Stamp::Driver {
            start_of_exposure: false,
        };
        let soe = Stamp::Driver {
            start_of_exposure: true,
        };
        let at = |s, e| mid_exposure_ns(s, driver, e, None, real, mono) as i128;
        assert_eq!(at(eof, None), real - 5_000_000);
        assert_eq!(at(eof, Some(2_000_000)), real - 6_000_000);
        assert_eq!(at(soe, Some(2_000_000)), real - 4_000_000);
        assert_eq!(at(Stamp::Dequeue, Some(2_000_000)), real);
        // A readout of 7 ms moves an end-of-frame stamp back; a start-of-exposure one is not
        // after the readout.
        let readout = Some(7_000_000);
        let at = |s, e| mid_exposure_ns(s, driver, e, readout, real, mono) as i128;
        assert_eq!(at(eof, Some(2_000_000)), real - 13_000_000);
        assert_eq!(at(soe, Some(2_000_000)), real - 4_000_000);
    }

    #[test]
    fn sequence_numbers_go_on_past_the_drivers_wrap() {
        let mut s = Sequence::default();
        assert_eq!(s.extend(u32::MAX - 1), u32::MAX as u64 - 1);
        assert_eq!(s.extend(u32::MAX), u32::MAX as u64);
        assert_eq!(s.extend(1), (1u64 << 32) + 1);
        // A driver that restarts at a small step back is not a wrap.
        assert_eq!(s.extend(0), 1u64 << 32);
    }
}
