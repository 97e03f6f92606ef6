//! The receiving side of a service, beside [`crate::Outlet`]: an [`Inlet<M>`] takes messages
//! of one type from iceoryx2 (a service on this PC) or from Zenoh (one or several keys), and
//! hands out only those that pass every check — the decoder's own (`Message::from_json` /
//! `from_binary`: size, schema, every field against `proto::messages::limits`), the rig's (a
//! message of another rig is `foreign`), and the caller's own expectation (a camera's
//! observation on that camera's key). A refused message changes nothing: it is counted in
//! [`Counters`] by its reason, named in health, and logged sparsely (the first ten, then at
//! each power of two), so a flood is counted in full without flooding the log.
//!
//! A service that forwards messages as they come (the viewer) uses the same checks through
//! [`listen`] and an [`Admission`].
//!
//! Zenoh delivers on its own threads: an inlet's callback only queues the bytes (at most
//! `capacity` of them; what does not fit is counted as dropped by [`Inlet::overflowed`]), and
//! decoding and checks run on the service's thread when it asks for the next message.

use crate::TransportError;
use crate::health::Counters;
use crate::iox::IoxService;
use crate::iox::MessageSubscriber;
use crate::net::{self, NetSubscriber};
use iceoryx2::node::Node;
use std::marker::PhantomData;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Duration;
use stereoscope_proto::messages::Message;

/// Why an inlet refused a message: the reason it is counted under, and what a person reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    pub reason: &'static str,
    pub message: String,
}

/// What a caller's expectation found wrong with a decoded message, for a person ("of camera
/// \"cam1\" on camera \"cam0\"'s channel"): the message is refused as `foreign`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Unexpected(pub String);

impl From<String> for Unexpected {
    fn from(what: String) -> Self {
        Unexpected(what)
    }
}

/// The caller's check of a decoded message that came on `key` (Zenoh key or iceoryx2 service
/// name).
type Expect<M> = Box<dyn Fn(&str, &M) -> Result<(), Unexpected> + Send + Sync>;

/// What a message of type `M` must be to be taken: it decodes (JSON from Zenoh, postcard from
/// iceoryx2 or where [`Admission::binary`] says so), it is of rig `rig`, and the caller's
/// expectation holds.
pub struct Admission<M> {
    /// What the messages are, in refusals ("observation", "pose frame").
    what: &'static str,
    rig: String,
    binary: bool,
    expect: Option<Expect<M>>,
}

impl<M> std::fmt::Debug for Admission<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Admission({} of rig {:?})", self.what, self.rig)
    }
}

impl<M: Message> Admission<M> {
    /// Messages of rig `rig`, called `what` in refusals, as JSON.
    pub fn new(rig: &str, what: &'static str) -> Self {
        Admission {
            what,
            rig: rig.to_string(),
            binary: false,
            expect: None,
        }
    }

    /// The messages come as postcard (the low-priority binary streams on Zenoh).
    pub fn binary(mut self) -> Self {
        self.binary = true;
        self
    }

    /// Refuses, as `foreign`, a message for which `expect(key, message)` says what is wrong.
    pub fn expecting(
        mut self,
        expect: impl Fn(&str, &M) -> Result<(), Unexpected> + Send + Sync + 'static,
    ) -> Self {
        self.expect = Some(Box::new(expect));
        self
    }

    /// Decodes and checks one message's bytes as they came on `key`.
    pub fn admit(&self, key: &str, bytes: &[u8]) -> Result<M, Refusal> {
        let decoded = if self.binary {
            M::from_binary(bytes)
        } else {
            M::from_json(bytes)
        };
        let m = decoded.map_err(|e| Refusal {
            reason: e.reason(),
            message: format!("{key}: {e}"),
        })?;
        if let Some(rig) = m.rig()
            && rig != self.rig
        {
            return Err(Refusal {
                reason: "foreign",
                message: format!("{key}: {} of rig {rig:?}, not {:?}", self.what, self.rig),
            });
        }
        if let Some(expect) = &self.expect
            && let Err(wrong) = expect(key, &m)
        {
            return Err(Refusal {
                reason: "foreign",
                message: format!("{key}: {} {wrong}", self.what),
            });
        }
        Ok(m)
    }
}

/// Hands every message on the Zenoh `keys` that `admission` takes to `on_message` (with its
/// bytes as they came), and every refusal to `on_refused`, on Zenoh's threads: for a service
/// that forwards as messages come (the viewer). Dropping the subscribers ends it.
pub fn listen<M: Message + 'static>(
    session: &zenoh::Session,
    keys: &[String],
    admission: Admission<M>,
    on_message: impl Fn(M, &[u8]) + Send + Sync + 'static,
    on_refused: impl Fn(Refusal) + Send + Sync + 'static,
) -> Result<Vec<NetSubscriber>, TransportError> {
    let shared = Arc::new((admission, on_message, on_refused));
    keys.iter()
        .map(|key| {
            let shared = shared.clone();
            net::subscribe(session, key, move |k, bytes| {
                let (admission, on_message, on_refused) = &*shared;
                match admission.admit(k, bytes) {
                    Ok(m) => on_message(m, bytes),
                    Err(r) => on_refused(r),
                }
            })
        })
        .collect()
}

enum Source {
    Iox(MessageSubscriber),
    Zenoh {
        queue: mpsc::Receiver<(String, Vec<u8>)>,
        overflow: Arc<AtomicU64>,
        /// Kept alive: dropping a subscriber undeclares it.
        subscribers: Vec<NetSubscriber>,
    },
}

/// Messages of type `M` from one place, decoded and checked.
pub struct Inlet<M> {
    admission: Admission<M>,
    source: Source,
    _message: PhantomData<fn() -> M>,
}

impl<M> std::fmt::Debug for Inlet<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.source {
            Source::Iox(s) => write!(f, "Inlet({:?}, iceoryx2 {})", self.admission, s.name()),
            Source::Zenoh { .. } => write!(f, "Inlet({:?}, Zenoh)", self.admission),
        }
    }
}

impl<M: Message> Inlet<M> {
    /// Messages of rig `rig` from iceoryx2 service `name` of `node` (postcard).
    pub fn iox(
        node: &Node<IoxService>,
        name: &str,
        rig: &str,
        what: &'static str,
    ) -> Result<Self, TransportError> {
        Ok(Inlet {
            admission: Admission::new(rig, what).binary(),
            source: Source::Iox(MessageSubscriber::new(node, name)?),
            _message: PhantomData,
        })
    }

    /// Messages of rig `rig` on the Zenoh keys (or key expressions) `keys` (JSON), at most
    /// `capacity` waiting.
    pub fn zenoh(
        session: &zenoh::Session,
        keys: &[String],
        rig: &str,
        what: &'static str,
        capacity: usize,
    ) -> Result<Self, TransportError> {
        let (tx, queue) = mpsc::sync_channel::<(String, Vec<u8>)>(capacity.max(1));
        let overflow = Arc::new(AtomicU64::new(0));
        let mut subscribers = Vec::with_capacity(keys.len());
        for key in keys {
            let tx = tx.clone();
            let overflow = overflow.clone();
            subscribers.push(net::subscribe(session, key, move |k, bytes| {
                if tx.try_send((k.to_string(), bytes.to_vec())).is_err() {
                    overflow.fetch_add(1, Ordering::Relaxed);
                }
            })?);
        }
        Ok(Inlet {
            admission: Admission::new(rig, what),
            source: Source::Zenoh {
                queue,
                overflow,
                subscribers,
            },
            _message: PhantomData,
        })
    }

    /// Refuses, as `foreign`, a message for which `expect(key, message)` says what is wrong.
    pub fn expecting(
        mut self,
        expect: impl Fn(&str, &M) -> Result<(), Unexpected> + Send + Sync + 'static,
    ) -> Self {
        self.admission = self.admission.expecting(expect);
        self
    }

    /// Stops taking new messages from Zenoh (those already queued can still be read): a
    /// service that drains its inlets as it stops calls this first.
    pub fn close(&mut self) {
        if let Source::Zenoh { subscribers, .. } = &mut self.source {
            subscribers.clear();
        }
    }

    /// Messages that arrived while `capacity` were already waiting (Zenoh only), since start.
    pub fn overflowed(&self) -> u64 {
        match &self.source {
            Source::Iox(_) => 0,
            Source::Zenoh { overflow, .. } => overflow.load(Ordering::Relaxed),
        }
    }

    /// The next message that passes, without waiting; refusals on the way are counted in
    /// `counters`, a failing subscriber is noted as its last error.
    pub fn try_next(&self, counters: &mut Counters) -> Option<M> {
        self.next_within(Duration::ZERO, counters)
    }

    /// The next message that passes, waiting up to `timeout` for one from Zenoh (an iceoryx2
    /// inlet does not wait: its service wakes on a listener).
    pub fn next_within(&self, timeout: Duration, counters: &mut Counters) -> Option<M> {
        self.receive(timeout, counters, |_| ()).map(|(m, ())| m)
    }

    /// [`Inlet::next_within`] with the message's bytes as they came (a recorder keeps them).
    pub fn next_with_bytes(
        &self,
        timeout: Duration,
        counters: &mut Counters,
    ) -> Option<(M, Vec<u8>)> {
        self.receive(timeout, counters, |b: &[u8]| b.to_vec())
    }

    /// The next message that passes, with what `keep` takes of its bytes.
    fn receive<K>(
        &self,
        timeout: Duration,
        counters: &mut Counters,
        keep: impl Fn(&[u8]) -> K,
    ) -> Option<(M, K)> {
        loop {
            let verdict = match &self.source {
                Source::Iox(sub) => {
                    match sub
                        .receive_with(|b| self.admission.admit(sub.name(), b).map(|m| (m, keep(b))))
                    {
                        Ok(Some(verdict)) => verdict,
                        Ok(None) => return None,
                        Err(e) => {
                            counters.note::<(), _>(Err(e));
                            return None;
                        }
                    }
                }
                Source::Zenoh { queue, .. } => {
                    let got = if timeout.is_zero() {
                        queue.try_recv().ok()
                    } else {
                        queue.recv_timeout(timeout).ok()
                    };
                    match got {
                        Some((key, bytes)) => self
                            .admission
                            .admit(&key, &bytes)
                            .map(|m| (m, keep(&bytes))),
                        None => return None,
                    }
                }
            };
            match verdict {
                Ok(got) => return Some(got),
                Err(r) => refuse(counters, &r),
            }
        }
    }
}

/// Counts `refusal` under its reason and logs it, sparsely: the first ten, then at each power
/// of two of the count.
pub fn refuse(counters: &mut Counters, refusal: &Refusal) {
    counters.reject(refusal.reason, &refusal.message);
    if counters.rejected <= 10 || counters.rejected.is_power_of_two() {
        tracing::warn!(
            "rejected {} ({} so far)",
            refusal.message,
            counters.rejected
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{Observation, SCHEMA_VERSION};

    fn observation(rig: &str, camera: &str) -> Observation {
        Observation {
            schema: SCHEMA_VERSION,
            rig: rig.into(),
            camera: camera.into(),
            sequence: 7,
            timestamp_ns: 1,
            frame_published_ns: 1,
            published_ns: 1,
            width_px: 640,
            height_px: 480,
            threshold: 100,
            dark: false,
            full_frame: true,
            dropped_blobs: 0,
            blobs: Vec::new(),
        }
    }

    /// What an inlet takes and what it refuses, each under its reason: a message of its rig
    /// that meets the expectation passes; another rig's, one on another camera's key, one
    /// that does not decode and one of another schema are refused, and counted.
    #[test]
    fn admission_takes_the_rigs_messages_and_names_each_refusal() {
        let a = Admission::<Observation>::new("lab", "observation").expecting(|key, o| {
            if key.ends_with(&o.camera) {
                Ok(())
            } else {
                Err(format!("of camera {:?} on {key}", o.camera).into())
            }
        });
        let ok = observation("lab", "cam0");
        assert_eq!(a.admit("obs/cam0", &ok.to_json()), Ok(ok.clone()));
        let r = a.admit("obs/cam0", &observation("other", "cam0").to_json());
        let r = r.unwrap_err();
        assert_eq!(r.reason, "foreign");
        assert!(r.message.contains("rig \"other\""), "{}", r.message);
        let r = a.admit("obs/cam1", &ok.to_json()).unwrap_err();
        assert_eq!(r.reason, "foreign");
        assert!(
            r.message.contains("of camera \"cam0\" on obs/cam1"),
            "{}",
            r.message
        );
        let r = a.admit("obs/cam0", b"{not json").unwrap_err();
        assert!(r.message.starts_with("obs/cam0: "), "{}", r.message);
        let mut old = ok.clone();
        old.schema = SCHEMA_VERSION + 1;
        let r = a.admit("obs/cam0", &old.to_json()).unwrap_err();
        assert_ne!(r.reason, "foreign");
        // Postcard where the admission says so.
        let b = Admission::<Observation>::new("lab", "observation").binary();
        assert_eq!(b.admit("iox", &ok.to_binary()), Ok(ok));
        assert!(b.admit("iox", b"\xff\xff").is_err());
        // Refusals are counted by reason.
        let mut c = Counters::default();
        refuse(&mut c, &r);
        refuse(
            &mut c,
            &Refusal {
                reason: "foreign",
                message: "x".into(),
            },
        );
        assert_eq!(c.rejected, 2);
        assert_eq!(
            c.detail.get("rejected.foreign").map(String::as_str),
            Some("1")
        );
        assert!(c.refusals().is_some_and(|s| s.starts_with("2 refused (")));
    }
}
