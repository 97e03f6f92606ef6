//! Zenoh: sessions opened on explicit endpoints (multicast scouting always off, so a test or a
//! lab network only sees what it was told to), and JSON publishers with the real-time QoS of
//! the pose stream. Each PC runs one router (in its launcher); its services connect to it as
//! clients, and routers of different PCs connect to each other (`docs/deploy.md`).

use crate::TransportError;
use stereoscope_proto::messages::Message;
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::qos::{CongestionControl, Priority};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZenohMode {
    Client,
    Peer,
    Router,
}

impl ZenohMode {
    pub fn parse(s: &str) -> Result<Self, TransportError> {
        match s {
            "client" => Ok(ZenohMode::Client),
            "peer" => Ok(ZenohMode::Peer),
            "router" => Ok(ZenohMode::Router),
            other => Err(TransportError::UnknownZenohMode(other.to_string())),
        }
    }

    fn as_str(self) -> &'static str {
        match self {
            ZenohMode::Client => "client",
            ZenohMode::Peer => "peer",
            ZenohMode::Router => "router",
        }
    }
}

/// A TCP port on 127.0.0.1 free right now and reserved for this process, for a router or a
/// test's endpoint. It comes from 20000–32767, below Linux's ephemeral range (32768 on), so the
/// kernel does not hand it to another socket (an outgoing connection, a `bind` to port 0)
/// between this call and its use. Every process that asks here holds a lock on the port's file
/// in `<temp>/stereoscope-ports/` until it exits, so two test processes (or two demos) never
/// get the same port; a port another program has bound is skipped. A program that binds the
/// port in between without asking here can still take it: a caller that binds must report
/// failure.
pub fn free_loopback_port() -> std::io::Result<u16> {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicU32, Ordering};
    const LOW: u32 = 20_000;
    const SPAN: u32 = 32_768 - LOW;
    static NEXT: AtomicU32 = AtomicU32::new(u32::MAX);
    // The locks this process holds: released when it exits.
    static HELD: Mutex<Vec<std::fs::File>> = Mutex::new(Vec::new());
    let dir = std::env::temp_dir().join("stereoscope-ports");
    std::fs::create_dir_all(&dir)?;
    let start = (std::process::id() % 64) * (SPAN / 64);
    let _ = NEXT.compare_exchange(u32::MAX, start, Ordering::SeqCst, Ordering::SeqCst);
    for _ in 0..SPAN {
        let port = (LOW + NEXT.fetch_add(1, Ordering::SeqCst) % SPAN) as u16;
        let lock = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(dir.join(port.to_string()))?;
        if lock.try_lock().is_err() {
            continue;
        }
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            HELD.lock().unwrap_or_else(|e| e.into_inner()).push(lock);
            return Ok(port);
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AddrInUse,
        "no free loopback port in 20000–32767",
    ))
}

/// How to join the Zenoh network.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ZenohSpec {
    pub mode: ZenohMode,
    /// Endpoints to connect to (`tcp/127.0.0.1:7447`).
    pub connect: Vec<String>,
    /// Endpoints to listen on.
    pub listen: Vec<String>,
    /// Certificates for `tls/` endpoints (mutual TLS: both ends show a certificate of the
    /// rig's authority).
    pub tls: Option<TlsFiles>,
    /// A Zenoh `access_control` document (JSON) for a router: who may publish what.
    pub access_control: Option<String>,
}

/// PEM files of one end of a mutual-TLS link: the authority both ends trust, and this end's
/// certificate and private key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    pub ca: std::path::PathBuf,
    pub cert: std::path::PathBuf,
    pub key: std::path::PathBuf,
}

impl ZenohSpec {
    /// A client of the router at `endpoint`.
    pub fn client_of(endpoint: &str) -> Self {
        ZenohSpec {
            mode: ZenohMode::Client,
            connect: vec![endpoint.to_string()],
            listen: Vec::new(),
            tls: None,
            access_control: None,
        }
    }

    /// A lone peer with no endpoints (a rig without `[[host]]`).
    pub fn lone_peer() -> Self {
        ZenohSpec {
            mode: ZenohMode::Peer,
            connect: Vec::new(),
            listen: Vec::new(),
            tls: None,
            access_control: None,
        }
    }

    /// Command-line form: `--zenoh-mode M --zenoh-connect E ... --zenoh-listen E ...`.
    pub fn to_args(&self) -> Vec<String> {
        let mut a = vec!["--zenoh-mode".to_string(), self.mode.as_str().to_string()];
        for e in &self.connect {
            a.push("--zenoh-connect".into());
            a.push(e.clone());
        }
        for e in &self.listen {
            a.push("--zenoh-listen".into());
            a.push(e.clone());
        }
        if let Some(t) = &self.tls {
            for (flag, path) in [
                ("--zenoh-tls-ca", &t.ca),
                ("--zenoh-tls-cert", &t.cert),
                ("--zenoh-tls-key", &t.key),
            ] {
                a.push(flag.into());
                a.push(path.display().to_string());
            }
        }
        a
    }
}

fn zerr(what: impl Into<String>, e: impl Into<zenoh::Error>) -> TransportError {
    TransportError::Zenoh {
        what: what.into(),
        source: crate::ZenohCause(e.into()),
    }
}

fn json_list(items: &[String]) -> String {
    serde_json::to_string(items).unwrap_or_else(|_| "[]".into())
}

/// Why a client could not reach its router, said for a person: the endpoint is TLS and no
/// certificate was given, nothing listens at its address (the rig seems not to be running
/// there), or it cannot be reached. `None` when the address takes a TCP connection.
pub fn why_unreachable(spec: &ZenohSpec) -> Option<String> {
    for endpoint in &spec.connect {
        let Some((protocol, rest)) = endpoint.split_once('/') else {
            continue;
        };
        let address = rest.split(['?', '#']).next().unwrap_or(rest);
        if protocol == "tls" && spec.tls.is_none() {
            return Some(format!(
                "{endpoint} is a TLS endpoint: give this PC's certificate with \
                 --zenoh-tls-ca, --zenoh-tls-cert and --zenoh-tls-key (deploy/make-certs.sh makes them)"
            ));
        }
        if protocol != "tcp" && protocol != "tls" {
            continue;
        }
        let Ok(mut addrs) = std::net::ToSocketAddrs::to_socket_addrs(address) else {
            return Some(format!(
                "{endpoint}: {address:?} is not an address this PC can resolve"
            ));
        };
        let Some(addr) = addrs.next() else { continue };
        match std::net::TcpStream::connect_timeout(&addr, std::time::Duration::from_secs(2)) {
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                return Some(format!(
                    "nothing listens at {endpoint}: the rig seems not to be running there \
                     (start it with `stereoscope run RIG.toml`), or its router listens elsewhere (--connect)"
                ));
            }
            Err(e) => return Some(format!("{endpoint} cannot be reached: {e}")),
        }
    }
    None
}

/// A client session to its router, failing at once with [`why_unreachable`]'s reason when the
/// router cannot be reached, and with a hint when something listens but no router answered.
pub fn open_client(spec: &ZenohSpec) -> Result<zenoh::Session, TransportError> {
    if let Some(why) = why_unreachable(spec) {
        return Err(TransportError::Unreachable(why));
    }
    open(spec).map_err(|e| match spec.connect.first() {
        Some(endpoint) if !endpoint.starts_with("tls/") => TransportError::Unreachable(format!(
            "{endpoint} takes connections but no Zenoh router answered ({}): if the rig's \
             links are TLS, connect to its tls/ endpoint with this PC's certificate",
            crate::error_chain(&e)
        )),
        _ => e,
    })
}

/// Batches in each link's real-time send queue (Zenoh allows 1–16; its default is 2).
pub const REAL_TIME_QUEUE_BATCHES: usize = 16;

/// Opens a session. A client waits up to 10 s for its router; peers and routers keep
/// retrying their `connect` endpoints in the background.
pub fn open(spec: &ZenohSpec) -> Result<zenoh::Session, TransportError> {
    let cfg = config(spec)?;
    let what = format!(
        "open {} session (connect {:?}, listen {:?})",
        spec.mode.as_str(),
        spec.connect,
        spec.listen
    );
    zenoh::open(cfg).wait().map_err(|e| zerr(what, e))
}

/// The Zenoh configuration [`open`] opens `spec` with.
fn config(spec: &ZenohSpec) -> Result<zenoh::Config, TransportError> {
    let mut cfg = zenoh::Config::default();
    let set = |cfg: &mut zenoh::Config, k: &str, v: &str| {
        cfg.insert_json5(k, v)
            .map_err(|e| zerr(format!("config {k} = {v}"), e))
    };
    set(&mut cfg, "mode", &format!("\"{}\"", spec.mode.as_str()))?;
    set(&mut cfg, "scouting/multicast/enabled", "false")?;
    set(&mut cfg, "connect/endpoints", &json_list(&spec.connect))?;
    set(&mut cfg, "listen/endpoints", &json_list(&spec.listen))?;
    if spec.mode == ZenohMode::Client {
        set(&mut cfg, "connect/timeout_ms", "10000")?;
        // Zenoh retries at 1, 3 and 7 s: a recorder started before its rig missed the first
        // 3.5 s of the take. Every 250 ms catches the router within a frame or two of its start.
        set(
            &mut cfg,
            "connect/retry",
            "{ period_init_ms: 100, period_max_ms: 250, period_increase_factor: 2 }",
        )?;
    }
    if spec.mode == ZenohMode::Router {
        // A router dials the other PCs' routers; Zenoh's default retries at 1, 3 and 7 s after a
        // link is lost, so a fusion PC's router restarted in 1 s waited for the 7 s attempt
        // (four cameras back 4.2 s after its kill in 1 run of the namespaces test, against
        // 1.1 s otherwise). Every 250 ms to 1 s bounds the wait at about a second.
        set(
            &mut cfg,
            "connect/retry",
            "{ period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2 }",
        )?;
    }
    if spec.mode != ZenohMode::Router {
        // Peers would otherwise listen on every interface; a client listens on nothing.
        set(&mut cfg, "scouting/gossip/enabled", "false")?;
    }
    if let Some(t) = &spec.tls {
        let tls = "transport/link/tls";
        for (key, path) in [
            ("root_ca_certificate", &t.ca),
            ("listen_certificate", &t.cert),
            ("listen_private_key", &t.key),
            ("connect_certificate", &t.cert),
            ("connect_private_key", &t.key),
        ] {
            let quoted = serde_json::to_string(&path.display().to_string())
                .unwrap_or_else(|_| "\"\"".into());
            set(&mut cfg, &format!("{tls}/{key}"), &quoted)?;
        }
        // Both ends show a certificate, and the one dialled must name the address dialled.
        set(&mut cfg, &format!("{tls}/enable_mtls"), "true")?;
        set(&mut cfg, &format!("{tls}/verify_name_on_connect"), "true")?;
    }
    if let Some(acl) = &spec.access_control {
        set(&mut cfg, "access_control", acl)?;
    }
    // Poses, observations and health go out at real-time priority, each message express (a
    // batch of its own), dropped after 1 ms when no batch is free. Zenoh's default of two
    // batches drops pose frames whenever the link's sending task is kept off the CPU for two
    // frames (a recording on a loaded 2-core PC lost 2–7 pose frames in 580); sixteen, the
    // most Zenoh allows, ride out such a stall (docs/recording.md).
    set(
        &mut cfg,
        "transport/link/tx/queue/size/real_time",
        &REAL_TIME_QUEUE_BATCHES.to_string(),
    )?;
    Ok(cfg)
}

/// Publishes messages as JSON on one key, express, real-time priority, dropping rather than
/// blocking when the network is congested (a stale pose is worth nothing).
pub struct JsonPublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
    key: String,
}

impl std::fmt::Debug for JsonPublisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "JsonPublisher({})", self.key)
    }
}

impl JsonPublisher {
    pub fn new(session: &zenoh::Session, key: &str) -> Result<Self, TransportError> {
        Self::declare(session, key, Encoding::APPLICATION_JSON, Priority::RealTime)
    }

    /// A publisher of binary messages (postcard) for people to look at — camera previews —
    /// at low priority, so they never delay poses on a shared link.
    pub fn binary_low_priority(
        session: &zenoh::Session,
        key: &str,
    ) -> Result<Self, TransportError> {
        Self::declare(
            session,
            key,
            Encoding::APPLICATION_OCTET_STREAM,
            Priority::DataLow,
        )
    }

    fn declare(
        session: &zenoh::Session,
        key: &str,
        encoding: Encoding,
        priority: Priority,
    ) -> Result<Self, TransportError> {
        let publisher = session
            .declare_publisher(key.to_string())
            .encoding(encoding)
            .congestion_control(CongestionControl::Drop)
            .priority(priority)
            .express(priority == Priority::RealTime)
            .wait()
            .map_err(|e| zerr(format!("declare publisher {key}"), e))?;
        Ok(JsonPublisher {
            publisher,
            key: key.to_string(),
        })
    }

    /// Whether any subscriber anywhere matches the key now (what is costly to make is only
    /// made while someone wants it).
    pub fn matching(&self) -> bool {
        self.publisher
            .matching_status()
            .wait()
            .map(|m| m.matching())
            .unwrap_or(false)
    }

    pub fn put<M: Message>(&self, msg: &M) -> Result<(), TransportError> {
        self.put_bytes(msg.to_json())
    }

    pub fn put_bytes(&self, bytes: Vec<u8>) -> Result<(), TransportError> {
        self.publisher
            .put(bytes)
            .wait()
            .map_err(|e| zerr(format!("put on {}", self.key), e))
    }
}

/// JSON messages on keys made as they come (one per object: `…/pose/<object_id>`), sent with
/// `Session::put`, nothing declared per key, and only while some subscriber's key meets the
/// keys' wildcard (one publisher declared on it, for its matching status alone).
///
/// Declaring a publisher per key cost the router about 3 kB for every key ever declared,
/// undeclared or not (`examples/key_churn.rs`: 20 000 keys took a router from 9.7 to 71 MB),
/// and a long run makes new object ids for ever; undeclared puts leave nothing behind (60 000
/// keys: the router flat at 12 MB). Undeclared puts are sent whether anyone listens or not,
/// which the declared publishers did not (a 2-minute soak: fusion 0.09 → 0.14 cores, the router
/// 0.03 → 0.07): hence the wildcard's matching status.
pub struct KeyedPublisher {
    session: zenoh::Session,
    wildcard: JsonPublisher,
}

impl std::fmt::Debug for KeyedPublisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "KeyedPublisher({})", self.wildcard.key)
    }
}

impl KeyedPublisher {
    /// Keys that `wildcard` (e.g. `stereoscope/<rig>/pose/*`) covers.
    pub fn new(session: &zenoh::Session, wildcard: &str) -> Result<Self, TransportError> {
        Ok(KeyedPublisher {
            session: session.clone(),
            wildcard: JsonPublisher::new(session, wildcard)?,
        })
    }

    /// Whether any subscriber anywhere meets the wildcard now: ask once for a batch of puts,
    /// and skip making them when not.
    pub fn matching(&self) -> bool {
        self.wildcard.matching()
    }

    /// Sends `bytes` (JSON) on `key` as [`JsonPublisher`] does: real-time priority, express,
    /// dropped rather than blocking when the link is congested.
    pub fn put_bytes(&self, key: &str, bytes: Vec<u8>) -> Result<(), TransportError> {
        self.session
            .put(key.to_string(), bytes)
            .encoding(Encoding::APPLICATION_JSON)
            .congestion_control(CongestionControl::Drop)
            .priority(Priority::RealTime)
            .express(true)
            .wait()
            .map_err(|e| zerr(format!("put {key}"), e))
    }
}

/// A Zenoh subscription made by [`subscribe`]: it lasts as long as this value.
pub type NetSubscriber = zenoh::pubsub::Subscriber<()>;

/// Subscribes to `key` and hands every payload with its key to `f` (on Zenoh's thread).
pub fn subscribe(
    session: &zenoh::Session,
    key: &str,
    mut f: impl FnMut(&str, &[u8]) + Send + Sync + 'static,
) -> Result<NetSubscriber, TransportError> {
    session
        .declare_subscriber(key.to_string())
        .callback_mut(move |sample| {
            let bytes = sample.payload().to_bytes();
            f(sample.key_expr().as_str(), &bytes);
        })
        .wait()
        .map_err(|e| zerr(format!("declare subscriber {key}"), e))
}

/// The keys of the liveliness tokens alive under `key` now (bounded by `timeout`).
pub fn alive(
    session: &zenoh::Session,
    key: &str,
    timeout: std::time::Duration,
) -> Result<Vec<String>, TransportError> {
    let replies = session
        .liveliness()
        .get(key.to_string())
        .timeout(timeout)
        .wait()
        .map_err(|e| zerr(format!("liveliness get {key}"), e))?;
    let mut out = Vec::new();
    while let Ok(reply) = replies.recv() {
        if let Ok(sample) = reply.result() {
            out.push(sample.key_expr().as_str().to_string());
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every mode's configuration is one Zenoh takes (a misspelt key fails at open, in every
    /// service, not here).
    #[test]
    fn every_modes_configuration_is_accepted() {
        for mode in [ZenohMode::Client, ZenohMode::Peer, ZenohMode::Router] {
            let spec = ZenohSpec {
                mode,
                ..ZenohSpec::client_of("tcp/127.0.0.1:7447")
            };
            let cfg = config(&spec).unwrap_or_else(|e| panic!("{mode:?}: {e}"));
            let queue = cfg
                .get_json("transport/link/tx/queue/size/real_time")
                .unwrap();
            assert_eq!(queue, REAL_TIME_QUEUE_BATCHES.to_string());
        }
        let client = config(&ZenohSpec::client_of("tcp/127.0.0.1:7447")).unwrap();
        let retry = client.get_json("connect/retry").unwrap();
        assert!(retry.contains("250"), "{retry}");
    }

    /// A client told why it cannot reach its router: a TLS endpoint without a certificate,
    /// and a port nothing listens on (the rig not running), each said at once.
    #[test]
    fn an_unreachable_router_is_explained() {
        let tls = ZenohSpec::client_of("tls/127.0.0.1:7447");
        let why = why_unreachable(&tls).unwrap_or_default();
        assert!(why.contains("--zenoh-tls-ca"), "{why}");
        // A port just freed: nothing listens on it.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .unwrap_or(1);
        let tcp = ZenohSpec::client_of(&format!("tcp/127.0.0.1:{port}"));
        let started = std::time::Instant::now();
        let e = open_client(&tcp).map(|_| ()).unwrap_err().to_string();
        assert!(
            e.contains("nothing listens") && e.contains("stereoscope run"),
            "{e}"
        );
        assert!(started.elapsed() < std::time::Duration::from_secs(5));
        // Something listening: nothing to say before trying.
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let here = ZenohSpec::client_of(&format!("tcp/{}", l.local_addr().unwrap()));
        assert_eq!(why_unreachable(&here), None);
    }

    /// Keyed puts reach a subscriber of one of the keys, each on its own key; the wildcard's
    /// matching status says whether anyone listens (a subscriber of one key is enough).
    #[test]
    fn keyed_puts_reach_a_subscriber_and_say_whether_anyone_listens() {
        let session = open(&ZenohSpec::lone_peer()).unwrap();
        let p = KeyedPublisher::new(&session, "t/pose/*").unwrap();
        assert!(!p.matching());
        let (tx, rx) = std::sync::mpsc::channel();
        let tx = std::sync::Mutex::new(tx);
        let sub = subscribe(&session, "t/pose/2", move |key, bytes| {
            if let Ok(tx) = tx.lock() {
                let _ = tx.send((key.to_string(), bytes.to_vec()));
            }
        })
        .unwrap();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        while !p.matching() && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(p.matching());
        for id in 1..=3 {
            p.put_bytes(
                &format!("t/pose/{id}"),
                format!("{{\"id\":{id}}}").into_bytes(),
            )
            .unwrap();
        }
        let got = rx.recv_timeout(std::time::Duration::from_secs(5)).unwrap();
        assert_eq!(got, ("t/pose/2".to_string(), b"{\"id\":2}".to_vec()));
        assert!(
            rx.recv_timeout(std::time::Duration::from_millis(200))
                .is_err()
        );
        drop(sub);
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        while p.matching() && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(!p.matching());
    }

    /// A port handed out stays reserved: its lock file cannot be taken by anyone else (a lock
    /// on another open of the file fails as another process's would), and this process does
    /// not hand it out twice.
    #[test]
    fn a_free_port_is_reserved_for_this_process() {
        let a = free_loopback_port().unwrap();
        let b = free_loopback_port().unwrap();
        assert_ne!(a, b);
        assert!((20_000..32_768).contains(&a), "{a}");
        let other = std::fs::OpenOptions::new()
            .write(true)
            .open(
                std::env::temp_dir()
                    .join("stereoscope-ports")
                    .join(a.to_string()),
            )
            .unwrap();
        assert!(other.try_lock().is_err());
        // Still free to bind for its owner.
        assert!(std::net::TcpListener::bind(("127.0.0.1", a)).is_ok());
    }
}
