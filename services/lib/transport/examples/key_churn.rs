//! What a long run's ever-new object keys cost in memory (issue 14, "memory flat over a soak"):
//! fusion publishes each object's poses on `…/pose/<object_id>`, and ids only grow. One role
//! per process, so that each one's resident memory can be read on its own:
//!
//!   key_churn router ENDPOINT
//!   key_churn sub ENDPOINT                 (subscribes to churn/pose/*, counts)
//!   key_churn pub ENDPOINT MODE KEYS LIVE [PER_KEY [RATE]]  (MODE: declared | put)
//!
//! `pub` publishes on KEYS distinct keys in turn, LIVE of them at a time, PER_KEY (20) messages
//! per key, at RATE messages a second (default: as fast as it can):
//! `declared` as fusion did (a publisher declared per key, dropped when the key's object is
//! gone), `put` with `Session::put` (nothing declared). Each role prints its resident memory
//! (kB) and CPU time every 2 s. `services/lib/transport/benches/key_churn.sh` runs all three.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::VecDeque;
use std::time::{Duration, Instant};
use stereoscope_transport::net::{ZenohMode, ZenohSpec, open};

fn rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1).map(str::to_string))
        })
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

/// CPU time this process used, seconds (user + system).
fn cpu_s() -> f64 {
    let ticks = std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1.to_string();
            let f: Vec<u64> = rest
                .split_whitespace()
                .skip(11)
                .take(2)
                .filter_map(|v| v.parse().ok())
                .collect();
            Some(f.iter().sum::<u64>())
        })
        .unwrap_or(0);
    ticks as f64 / 100.0
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let role = args.get(1).map(String::as_str).unwrap_or("");
    let endpoint = args.get(2).cloned().unwrap_or_default();
    match role {
        "router" => {
            let spec = ZenohSpec {
                mode: ZenohMode::Router,
                connect: Vec::new(),
                listen: vec![endpoint],
                tls: None,
                access_control: None,
            };
            let _s = open(&spec).unwrap();
            loop {
                println!("router rss_kb {} cpu_s {:.2}", rss_kb(), cpu_s());
                std::thread::sleep(Duration::from_secs(2));
            }
        }
        "sub" => {
            let s = open(&ZenohSpec::client_of(&endpoint)).unwrap();
            let count = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
            let c = count.clone();
            let _sub = stereoscope_transport::net::subscribe(&s, "churn/pose/*", move |_, _| {
                c.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            })
            .unwrap();
            loop {
                println!(
                    "sub rss_kb {} cpu_s {:.2} received {}",
                    rss_kb(),
                    cpu_s(),
                    count.load(std::sync::atomic::Ordering::Relaxed)
                );
                std::thread::sleep(Duration::from_secs(2));
            }
        }
        "pub" => {
            let mode = args[3].clone();
            let keys: u64 = args[4].parse().unwrap();
            let live: usize = args[5].parse().unwrap();
            let per_key: u64 = args.get(6).and_then(|v| v.parse().ok()).unwrap_or(20);
            // Messages a second (0: as fast as it can).
            let rate: f64 = args.get(7).and_then(|v| v.parse().ok()).unwrap_or(0.0);
            let start = Instant::now();
            let mut sent = 0u64;
            let s = open(&ZenohSpec::client_of(&endpoint)).unwrap();
            let mut declared: VecDeque<(u64, zenoh::pubsub::Publisher<'static>)> = VecDeque::new();
            let mut last = Instant::now();
            let payload = vec![b'x'; 300];
            for k in 0..keys {
                let key = format!("churn/pose/{k}");
                for _ in 0..per_key {
                    sent += 1;
                    if rate > 0.0 {
                        let due = start + Duration::from_secs_f64(sent as f64 / rate);
                        if let Some(wait) = due.checked_duration_since(Instant::now()) {
                            std::thread::sleep(wait);
                        }
                    }
                    if mode == "declared" {
                        if declared.back().is_none_or(|(id, _)| *id != k) {
                            let p = zenoh::Wait::wait(s.declare_publisher(key.clone())).unwrap();
                            declared.push_back((k, p));
                            if declared.len() > live {
                                declared.pop_front();
                            }
                        }
                        if let Some((_, p)) = declared.back() {
                            zenoh::Wait::wait(p.put(payload.clone())).unwrap();
                        }
                    } else {
                        zenoh::Wait::wait(s.put(key.clone(), payload.clone())).unwrap();
                    }
                }
                if last.elapsed() > Duration::from_secs(2) {
                    println!("pub rss_kb {} keys {k}", rss_kb());
                    last = Instant::now();
                }
            }
            drop(declared);
            std::thread::sleep(Duration::from_secs(3));
            println!(
                "pub rss_kb {} cpu_s {:.2} keys {keys} done",
                rss_kb(),
                cpu_s()
            );
        }
        _ => panic!("usage: key_churn router|sub|pub ENDPOINT [MODE KEYS LIVE]"),
    }
}
