//! iceoryx2 on one PC: a node under the rig's prefix, frame publishers and subscribers (zero
//! copy, `[u8]` payload with a `FrameHeader` user header), message publishers and subscribers
//! (postcard bytes), each paired with an event service so a reader sleeps until a writer
//! notifies, and the cleanup of dead nodes' leftovers.

use crate::TransportError;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::time::Duration;
use stereoscope_proto::frame::FrameHeader;
use stereoscope_proto::messages::Message;
use stereoscope_proto::names::iox as names;

pub type IoxService = ipc::Service;

fn err(
    what: &'static str,
    name: &str,
    e: impl std::error::Error + Send + Sync + 'static,
) -> TransportError {
    TransportError::Iox {
        what,
        name: name.to_string(),
        source: Box::new(e),
    }
}

/// The iceoryx2 configuration for files under `prefix`.
pub fn config(prefix: &str) -> Result<Config, TransportError> {
    let mut cfg = Config::default();
    cfg.global.prefix = FileName::new(prefix.as_bytes())
        .map_err(|_| TransportError::BadPrefix(prefix.to_string()))?;
    Ok(cfg)
}

/// A node named `name` under `prefix`. Signals are left to the caller ([`crate::Shutdown`]).
pub fn node(prefix: &str, name: &str) -> Result<Node<IoxService>, TransportError> {
    let cfg = config(prefix)?;
    let node_name = NodeName::new(name).map_err(|e| err("node name", name, e))?;
    NodeBuilder::new()
        .name(&node_name)
        .config(&cfg)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IoxService>()
        .map_err(|e| err("node", name, e))
}

/// Removes what dead processes left behind under `prefix`; returns how many nodes it cleaned.
pub fn cleanup_dead_nodes(prefix: &str) -> Result<usize, TransportError> {
    let cfg = config(prefix)?;
    let mut cleaned = 0;
    Node::<IoxService>::list(&cfg, |state| {
        if let NodeState::<IoxService>::Dead(view) = state
            && view.try_remove_stale_resources().is_ok()
        {
            cleaned += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("node list", prefix, e))?;
    Ok(cleaned)
}

/// Whether `file` (a name in `/dev/shm`) is the node registry iceoryx2 keeps for `prefix`:
/// `<prefix><40 hex digits>_node.<digits and _>.global_mgmt`. Strict, so that prefix `stsc_`
/// never matches another rig's `stsc_demo12_…` file.
pub fn is_prefix_registry(file: &str, prefix: &str) -> bool {
    let Some(rest) = file.strip_prefix(prefix) else {
        return false;
    };
    let Some((hash, tail)) = rest.split_once('_') else {
        return false;
    };
    let Some(version) = tail
        .strip_prefix("node.")
        .and_then(|t| t.strip_suffix(".global_mgmt"))
    else {
        return false;
    };
    hash.len() == 40
        && hash.bytes().all(|b| b.is_ascii_hexdigit())
        && !version.is_empty()
        && version.bytes().all(|b| b.is_ascii_digit() || b == b'_')
}

/// After a clean stop: when no iceoryx2 node of `prefix` is alive any more (dead ones are
/// cleaned first), removes the node registry iceoryx2 leaves in `/dev/shm` for the prefix, so
/// that runs leave nothing behind. Returns whether the prefix is now clear; a prefix still in
/// use (another process of the same rig and PC) is left alone.
pub fn release_prefix(prefix: &str) -> Result<bool, TransportError> {
    cleanup_dead_nodes(prefix)?;
    let cfg = config(prefix)?;
    let mut others = 0;
    Node::<IoxService>::list(&cfg, |state| {
        if !matches!(state, NodeState::<IoxService>::Dead(_)) {
            others += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("node list", prefix, e))?;
    if others > 0 {
        return Ok(false);
    }
    let Ok(entries) = std::fs::read_dir("/dev/shm") else {
        return Ok(true);
    };
    for e in entries.flatten() {
        if let Some(name) = e.file_name().to_str()
            && is_prefix_registry(name, prefix)
        {
            let _ = std::fs::remove_file(e.path());
        }
    }
    Ok(true)
}

fn service_name(name: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(name).map_err(|e| err("service name", name, e))
}

fn event_service(
    node: &Node<IoxService>,
    name: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<IoxService>, TransportError> {
    node.service_builder(&service_name(name)?)
        .event()
        .max_notifiers(names::MAX_NOTIFIERS)
        .max_listeners(names::MAX_LISTENERS)
        .max_nodes(names::MAX_NODES)
        .open_or_create()
        .map_err(|e| err("event service", name, e))
}

/// A listener that wakes when any notifier of `name` fires.
pub struct Waker {
    listener: Listener<IoxService>,
}

impl std::fmt::Debug for Waker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Waker")
    }
}

impl Waker {
    pub fn new(node: &Node<IoxService>, name: &str) -> Result<Self, TransportError> {
        let listener = event_service(node, name)?
            .listener_builder()
            .create()
            .map_err(|e| err("listener", name, e))?;
        Ok(Waker { listener })
    }

    /// Waits up to `timeout` for a notification; drains every pending one. Returns whether
    /// one came.
    pub fn wait(&self, timeout: Duration) -> bool {
        matches!(self.listener.timed_wait(|_| {}, timeout), Ok(n) if n > 0)
    }
}

/// What a frame's writer knows better than the header it was given.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameStamp {
    /// When the frame was exposed (a camera's driver time, a recording's time).
    pub timestamp_ns: Option<u64>,
    /// The number the live camera gave it (a recording's).
    pub sequence: Option<u64>,
}

/// Publishes frames of one camera.
pub struct FramePublisher {
    publisher: Publisher<IoxService, [u8], FrameHeader>,
    notifier: Notifier<IoxService>,
    name: String,
}

impl std::fmt::Debug for FramePublisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FramePublisher({})", self.name)
    }
}

fn frame_service(
    node: &Node<IoxService>,
    name: &str,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<IoxService, [u8], FrameHeader>,
    TransportError,
> {
    let eight = Alignment::new(8).ok_or_else(|| TransportError::Alignment(name.to_string()))?;
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<[u8]>()
        .user_header::<FrameHeader>()
        .payload_alignment(eight)
        .enable_safe_overflow(true)
        .history_size(names::FRAME_HISTORY)
        .subscriber_max_buffer_size(names::FRAME_BUFFER)
        .subscriber_max_borrowed_samples(names::FRAME_BORROWED)
        .max_subscribers(names::MAX_SUBSCRIBERS)
        .max_publishers(names::MAX_PUBLISHERS)
        .max_nodes(names::MAX_NODES)
        .open_or_create()
        .map_err(|e| err("frame service", name, e))
}

impl FramePublisher {
    /// `max_frame_bytes`: the largest frame this camera will publish.
    pub fn new(
        node: &Node<IoxService>,
        name: &str,
        max_frame_bytes: usize,
    ) -> Result<Self, TransportError> {
        let publisher = frame_service(node, name)?
            .publisher_builder()
            .initial_max_slice_len(max_frame_bytes.max(1))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(2)
            .create()
            .map_err(|e| err("frame publisher", name, e))?;
        let notifier = event_service(node, name)?
            .notifier_builder()
            .create()
            .map_err(|e| err("notifier", name, e))?;
        Ok(FramePublisher {
            publisher,
            notifier,
            name: name.to_string(),
        })
    }

    /// Loans `header.payload_len()` bytes of shared memory for one frame: write the pixels
    /// in place ([`FrameLoan::pixels_mut`]), then [`FrameLoan::send`] it, or drop the loan to
    /// send nothing.
    pub fn loan(&self, header: FrameHeader) -> Result<FrameLoan<'_>, TransportError> {
        let len = header.payload_len() as usize;
        let sample = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| err("frame loan", &self.name, e))?;
        // Zero-initialise once (a memset at memory speed), then let the source write.
        let sample = sample.write_from_fn(|_| 0u8);
        Ok(FrameLoan {
            sample,
            header,
            publisher: self,
        })
    }
}

/// One frame's shared memory, loaned from a [`FramePublisher`]: the pixels are written in
/// place, then the frame is sent with its stamp, or dropped unsent.
pub struct FrameLoan<'a> {
    sample: iceoryx2::sample_mut::SampleMut<IoxService, [u8], FrameHeader>,
    header: FrameHeader,
    publisher: &'a FramePublisher,
}

impl std::fmt::Debug for FrameLoan<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "FrameLoan({} {})",
            self.publisher.name, self.header.sequence
        )
    }
}

impl FrameLoan<'_> {
    /// The frame's payload, `header.payload_len()` bytes, zeroed.
    pub fn pixels_mut(&mut self) -> &mut [u8] {
        self.sample.payload_mut()
    }

    /// Sends the frame, with the exposure time and sequence number from `stamp` where the
    /// writer knows better ones than the header's, and `published_ns` now. Returns how many
    /// subscribers got it.
    pub fn send(mut self, stamp: FrameStamp) -> Result<usize, TransportError> {
        let mut header = self.header;
        header.timestamp_ns = stamp.timestamp_ns.unwrap_or(header.timestamp_ns);
        header.sequence = stamp.sequence.unwrap_or(header.sequence);
        header.published_ns = stereoscope_proto::messages::now_ns();
        *self.sample.user_header_mut() = header;
        let n = self
            .sample
            .send()
            .map_err(|e| err("frame send", &self.publisher.name, e))?;
        let _ = self.publisher.notifier.notify();
        Ok(n)
    }
}

impl FramePublisher {
    /// Publishes `payload` with `header` as given, without checking that they agree: what a
    /// faulty or foreign writer could put in shared memory, for testing readers.
    pub fn publish_unchecked(
        &self,
        header: FrameHeader,
        payload: &[u8],
    ) -> Result<usize, TransportError> {
        let mut sample = self
            .publisher
            .loan_slice_uninit(payload.len())
            .map_err(|e| err("frame loan", &self.name, e))?
            .write_from_slice(payload);
        *sample.user_header_mut() = header;
        let n = sample
            .send()
            .map_err(|e| err("frame send", &self.name, e))?;
        let _ = self.notifier.notify();
        Ok(n)
    }
}

/// Reads frames of one camera.
pub struct FrameSubscriber {
    subscriber: Subscriber<IoxService, [u8], FrameHeader>,
    waker: Waker,
    name: String,
}

impl std::fmt::Debug for FrameSubscriber {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FrameSubscriber({})", self.name)
    }
}

pub type FrameSample = iceoryx2::sample::Sample<IoxService, [u8], FrameHeader>;

impl FrameSubscriber {
    pub fn new(node: &Node<IoxService>, name: &str) -> Result<Self, TransportError> {
        let subscriber = frame_service(node, name)?
            .subscriber_builder()
            .create()
            .map_err(|e| err("frame subscriber", name, e))?;
        Ok(FrameSubscriber {
            subscriber,
            waker: Waker::new(node, name)?,
            name: name.to_string(),
        })
    }

    /// The oldest frame waiting, without waiting (for readers that want every frame: the
    /// recorder).
    pub fn next_oldest(&self) -> Result<Option<FrameSample>, TransportError> {
        self.subscriber
            .receive()
            .map_err(|e| err("frame receive", &self.name, e))
    }

    /// The newest frame waiting (older ones are released unread and counted in the second
    /// value), or `None` after `timeout`.
    pub fn next_newest(
        &self,
        timeout: Duration,
    ) -> Result<Option<(FrameSample, u64)>, TransportError> {
        let mut skipped = 0u64;
        let mut newest = None;
        for attempt in 0..2 {
            loop {
                match self.subscriber.receive() {
                    Ok(Some(s)) => {
                        if newest.is_some() {
                            skipped += 1;
                        }
                        newest = Some(s);
                    }
                    Ok(None) => break,
                    Err(e) => return Err(err("frame receive", &self.name, e)),
                }
            }
            if newest.is_some() || attempt == 1 {
                break;
            }
            if !self.waker.wait(timeout) {
                // A notification may have been missed between receive and wait: look once more.
                continue;
            }
        }
        Ok(newest.map(|s| (s, skipped)))
    }
}

/// Publishes one kind of message (postcard bytes) and notifies `notify` (its own name when
/// `None`).
pub struct MessagePublisher {
    publisher: Publisher<IoxService, [u8], ()>,
    notifiers: Vec<Notifier<IoxService>>,
    name: String,
}

impl std::fmt::Debug for MessagePublisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MessagePublisher({})", self.name)
    }
}

fn message_service(
    node: &Node<IoxService>,
    name: &str,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<IoxService, [u8], ()>,
    TransportError,
> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<[u8]>()
        .enable_safe_overflow(true)
        .history_size(0)
        .subscriber_max_buffer_size(names::MESSAGE_BUFFER)
        .subscriber_max_borrowed_samples(2)
        .max_subscribers(names::MAX_SUBSCRIBERS)
        .max_publishers(names::MAX_PUBLISHERS)
        .max_nodes(names::MAX_NODES)
        .open_or_create()
        .map_err(|e| err("message service", name, e))
}

impl MessagePublisher {
    pub fn new(
        node: &Node<IoxService>,
        name: &str,
        also_notify: &[&str],
    ) -> Result<Self, TransportError> {
        let publisher = message_service(node, name)?
            .publisher_builder()
            .initial_max_slice_len(names::MESSAGE_INITIAL_BYTES)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| err("message publisher", name, e))?;
        let mut notifiers = Vec::new();
        for n in std::iter::once(name).chain(also_notify.iter().copied()) {
            notifiers.push(
                event_service(node, n)?
                    .notifier_builder()
                    .create()
                    .map_err(|e| err("notifier", n, e))?,
            );
        }
        Ok(MessagePublisher {
            publisher,
            notifiers,
            name: name.to_string(),
        })
    }

    pub fn publish<M: Message>(&self, msg: &M) -> Result<usize, TransportError> {
        let bytes = msg.to_binary();
        if bytes.len() > names::MESSAGE_MAX_BYTES {
            return Err(TransportError::MessageTooLarge {
                name: self.name.clone(),
                bytes: bytes.len(),
                max: names::MESSAGE_MAX_BYTES,
            });
        }
        let sample = self
            .publisher
            .loan_slice_uninit(bytes.len())
            .map_err(|e| err("message loan", &self.name, e))?;
        let sample = sample.write_from_slice(&bytes);
        let n = sample
            .send()
            .map_err(|e| err("message send", &self.name, e))?;
        for nt in &self.notifiers {
            let _ = nt.notify();
        }
        Ok(n)
    }
}

/// Reads one kind of message.
pub struct MessageSubscriber {
    subscriber: Subscriber<IoxService, [u8], ()>,
    name: String,
}

impl std::fmt::Debug for MessageSubscriber {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MessageSubscriber({})", self.name)
    }
}

impl MessageSubscriber {
    pub fn new(node: &Node<IoxService>, name: &str) -> Result<Self, TransportError> {
        let subscriber = message_service(node, name)?
            .subscriber_builder()
            .create()
            .map_err(|e| err("message subscriber", name, e))?;
        Ok(MessageSubscriber {
            subscriber,
            name: name.to_string(),
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// The next message's payload, handed to `f` while the sample is held.
    pub fn receive_with<R>(&self, f: impl FnOnce(&[u8]) -> R) -> Result<Option<R>, TransportError> {
        match self.subscriber.receive() {
            Ok(Some(s)) => Ok(Some(f(s.payload()))),
            Ok(None) => Ok(None),
            Err(e) => Err(err("message receive", &self.name, e)),
        }
    }

    /// The next message, if any: `Some(Err)` for a payload that does not decode (the caller
    /// reports it and goes on).
    pub fn try_next<M: Message>(
        &self,
    ) -> Result<Option<Result<M, stereoscope_proto::messages::DecodeError>>, TransportError> {
        match self.subscriber.receive() {
            Ok(Some(s)) => Ok(Some(M::from_binary(s.payload()))),
            Ok(None) => Ok(None),
            Err(e) => Err(err("message receive", &self.name, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HASH: &str = "9204dd183d1c4d8e1ff592a30766ffa6765aa8b5";

    #[test]
    fn only_the_prefixs_own_registry_matches() {
        let f = |p: &str| format!("{p}{HASH}_node.0_10_0.global_mgmt");
        assert!(is_prefix_registry(&f("stsc_"), "stsc_"));
        assert!(is_prefix_registry(&f("stsc_demo12_"), "stsc_demo12_"));
        // Another rig's file under a longer prefix, even one that looks hexadecimal.
        assert!(!is_prefix_registry(&f("stsc_demo12_"), "stsc_"));
        assert!(!is_prefix_registry(&f("stsc_abc_"), "stsc_"));
        assert!(!is_prefix_registry(&f("stsc_demo1_"), "stsc_demo12_"));
        assert!(!is_prefix_registry(
            &format!("stsc_{HASH}_node.0_10_0.global_mgmt.bak"),
            "stsc_"
        ));
        assert!(!is_prefix_registry("stsc_1234.event", "stsc_"));
    }

    /// A prefix whose nodes have all gone leaves nothing in `/dev/shm`; one still in use is
    /// left alone.
    #[test]
    fn a_released_prefix_leaves_no_file() {
        let prefix = format!("stsc_rel{}_", std::process::id());
        let ours = || {
            std::fs::read_dir("/dev/shm")
                .map(|d| {
                    d.flatten()
                        .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
                        .count()
                })
                .unwrap_or(0)
        };
        let n = node(&prefix, "release-test").unwrap();
        assert!(ours() > 0, "iceoryx2 made no file in /dev/shm");
        assert!(
            !release_prefix(&prefix).unwrap(),
            "released while a node lives"
        );
        assert!(ours() > 0);
        drop(n);
        assert!(release_prefix(&prefix).unwrap());
        assert_eq!(ours(), 0);
    }
}
