//! The skeleton every service stands on: a node started in one call (iceoryx2 node, Zenoh
//! session, liveliness token and health reports, the counters they report), and an outlet that
//! publishes one message on the same PC (iceoryx2, zero-copy) and to the network (Zenoh) at
//! once. A service is then its setup (`ServiceNode::start`, its inputs and outlets) and its
//! step, in a short `run(config, shutdown)`; `docs/architecture.md` shows how to add one.

use crate::TransportError;
use crate::health::{Counters, HealthReporter};
use crate::iox::{IoxService, MessagePublisher};
use crate::net::{self, JsonPublisher, ZenohSpec};
use iceoryx2::prelude::Node;
use std::marker::PhantomData;
use stereoscope_proto::messages::Message;

/// Who a service is and where it joins: what [`ServiceNode::start`] needs.
#[derive(Debug, Clone, Copy)]
pub struct NodeSpec<'a> {
    pub rig: &'a str,
    pub host: &'a str,
    /// The service's name, at most one `/` (`moments/cam0`).
    pub service: &'a str,
    pub iox_prefix: &'a str,
    pub zenoh: &'a ZenohSpec,
    /// Where no second instance may run.
    pub exclusive: Exclusive,
}

/// Where a service must be the only one of its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exclusive {
    /// One in the whole rig (a camera's capture and worker, fusion).
    Rig,
    /// One per host (a serial port's output).
    Host,
    /// Any number (recorders).
    No,
}

/// A running service's connections: its iceoryx2 node, its Zenoh session, and its health.
pub struct ServiceNode {
    pub iox: Node<IoxService>,
    pub session: zenoh::Session,
    pub counters: Counters,
    health: HealthReporter,
    rig: String,
    service: String,
    iox_prefix: String,
}

impl std::fmt::Debug for ServiceNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ServiceNode({}/{})", self.rig, self.service)
    }
}

impl ServiceNode {
    /// Creates the iceoryx2 node (named after the service, `/` as `-`), opens the Zenoh
    /// session and declares the service alive.
    /// A service that must be the only one of its name ([`NodeSpec::exclusive`]) and finds
    /// another alive is refused with [`TransportError::AlreadyRunning`], naming its host.
    pub fn start(spec: NodeSpec<'_>) -> Result<Self, TransportError> {
        let session = net::open(spec.zenoh)?;
        let key = match spec.exclusive {
            Exclusive::Rig => Some(format!("stereoscope/{}/alive/*/{}", spec.rig, spec.service)),
            Exclusive::Host => Some(stereoscope_proto::names::zenoh::alive(
                spec.rig,
                spec.host,
                spec.service,
            )),
            Exclusive::No => None,
        };
        if let Some(key) = key {
            let prefix = format!("stereoscope/{}/alive/", spec.rig);
            let suffix = format!("/{}", spec.service);
            let running = net::alive(&session, &key, std::time::Duration::from_millis(500))?;
            if let Some(other) = running.first() {
                let host = other
                    .strip_prefix(&prefix)
                    .and_then(|k| k.strip_suffix(&suffix))
                    .unwrap_or(other);
                return Err(TransportError::AlreadyRunning {
                    service: spec.service.to_string(),
                    host: host.to_string(),
                });
            }
        }
        let iox = crate::iox::node(spec.iox_prefix, &spec.service.replace('/', "-"))?;
        let health = HealthReporter::new(&session, spec.rig, spec.host, spec.service)?;
        Ok(ServiceNode {
            iox,
            session,
            counters: Counters::default(),
            health,
            rig: spec.rig.to_string(),
            service: spec.service.to_string(),
            iox_prefix: spec.iox_prefix.to_string(),
        })
    }

    pub fn rig(&self) -> &str {
        &self.rig
    }

    /// An outlet publishing on iceoryx2 service `iox_name` (waking the listeners of
    /// `also_notify` too) and on Zenoh key `key`.
    pub fn outlet<M: Message>(
        &self,
        iox_name: &str,
        also_notify: &[&str],
        key: &str,
    ) -> Result<Outlet<M>, TransportError> {
        Ok(Outlet {
            local: MessagePublisher::new(&self.iox, iox_name, also_notify)?,
            remote: JsonPublisher::new(&self.session, key)?,
            published: 0,
            _message: PhantomData,
        })
    }

    /// Whether the next [`ServiceNode::tick`] reports: fill `counters.detail` only then.
    pub fn report_due(&self) -> bool {
        self.health.due()
    }

    /// Reports health when a report is due (once a second).
    pub fn tick(&mut self) {
        self.health.tick(&self.counters);
    }

    /// Reports health now: a service's last report as it stops, with its final counts.
    pub fn finish(&mut self) {
        self.health.report(&self.counters);
    }
}

/// One kind of message published both on this PC (iceoryx2) and on the network (Zenoh).
pub struct Outlet<M> {
    local: MessagePublisher,
    remote: JsonPublisher,
    published: u64,
    _message: PhantomData<fn(&M)>,
}

impl<M> std::fmt::Debug for Outlet<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Outlet({:?}, {} published)", self.local, self.published)
    }
}

impl<M: Message> Outlet<M> {
    /// Publishes `msg` on both; a side that fails is noted in `counters` as the last error and
    /// the other still gets it. Returns whether both took it.
    pub fn publish(&mut self, msg: &M, counters: &mut Counters) -> bool {
        let local = self.local.publish(msg);
        let remote = self.remote.put(msg);
        let ok = local.is_ok() && remote.is_ok();
        counters.note(local);
        counters.note(remote);
        self.published += 1;
        ok
    }

    /// Messages published so far.
    pub fn published(&self) -> u64 {
        self.published
    }
}

/// What a service's step says about the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Step again (after the health tick).
    Continue,
    /// The service is done: its source ended, or it reached its `max_*` count.
    Stop,
}

/// A service as setup plus step: the setup builds a value of this type (node, inputs,
/// outlets, state); [`drive`] steps it until shutdown or [`Flow::Stop`].
pub trait Service {
    /// What `run` returns when the service stops cleanly (its counts).
    type Summary;
    type Error;

    /// The node the service stands on, for the health tick and the last report.
    fn node(&mut self) -> &mut ServiceNode;

    /// One pass: wait a bounded time for input, handle what came, publish. A step that
    /// returns an error ends the service (permanent failures only: a bad frame or message is
    /// counted and skipped inside the step).
    fn step(&mut self, shutdown: &crate::Shutdown) -> Result<Flow, Self::Error>;

    /// Stop once the node's `counters.processed` reaches this (a `max_*` count: tests and
    /// benchmarks). [`drive`] checks it before every step.
    fn limit(&self) -> Option<u64> {
        None
    }

    /// Once after the last step, before the last health report: flush what is buffered.
    fn stop(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    fn summary(&self) -> Self::Summary;
}

/// The loop every service runs: step, report health when due, until shutdown is requested,
/// the service's [`Service::limit`] is reached or a step says stop; then `stop` and a last health report, also when a step failed.
pub fn drive<S: Service>(
    mut service: S,
    shutdown: &crate::Shutdown,
) -> Result<S::Summary, S::Error> {
    let stepped = loop {
        if shutdown.requested() {
            break Ok(());
        }
        if let Some(limit) = service.limit()
            && service.node().counters.processed >= limit
        {
            break Ok(());
        }
        match service.step(shutdown) {
            Ok(Flow::Continue) => service.node().tick(),
            Ok(Flow::Stop) => break Ok(()),
            Err(e) => break Err(e),
        }
    };
    let stopped = service.stop();
    service.node().finish();
    let summary = service.summary();
    // A service run on its own removes its prefix's iceoryx2 files as it stops, once no other
    // process uses them: nothing stays behind in /dev/shm. Under a launcher (which names its
    // session in the environment) the launcher does it after the last service, so a service
    // that ends early never pulls them from under one being restarted.
    let prefix = service.node().iox_prefix.clone();
    drop(service);
    if std::env::var_os(stereoscope_proto::names::SESSION_ENV).is_none()
        && let Err(e) = crate::iox::release_prefix(&prefix)
    {
        tracing::warn!("cleaning up iceoryx2 files of {prefix}: {e}");
    }
    stepped?;
    stopped?;
    Ok(summary)
}
