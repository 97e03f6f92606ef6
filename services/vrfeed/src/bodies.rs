//! The bodies the feed serves, and their changes while it runs (`docs/bodies.md`, "Changing
//! bodies while the rig runs").
//!
//! Every protocol names a body by a number its clients keep: VRPN's sender id, NatNet's rigid
//! body id, Qualisys's place in the 6D list, LSL's channels. So the feed keeps a table in
//! which a body keeps its index for as long as the feed runs: a body whose markers change
//! keeps its place, a new body is appended, and a body taken out of the rig keeps its place and
//! is simply never tracked again (as Motive reports a disabled asset) until the feed restarts.
//! A renamed body is a new body.

use crate::output::BodyDef;
use crate::{VrFeedService, ros2};
use nalgebra::Point3;
use stereoscope_bodies::filter::PoseFilter;
use stereoscope_proto::messages::Detail;
use stereoscope_rig::watch::Change;

/// The rig's bodies with their markers in metres, in rig order.
pub fn body_defs(spec: &stereoscope_rig::schema::RigFile) -> Vec<BodyDef> {
    let s = spec.units.metres();
    spec.bodies
        .iter()
        .map(|b| BodyDef {
            name: b.name.clone(),
            markers_m: b
                .markers
                .iter()
                .map(|m| Point3::new(m[0] * s, m[1] * s, m[2] * s))
                .collect(),
        })
        .collect()
}

/// The feed's bodies by stable index.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BodyTable {
    defs: Vec<BodyDef>,
}

impl BodyTable {
    pub fn new(rig: &[BodyDef]) -> BodyTable {
        let mut t = BodyTable::default();
        t.merge(rig);
        t
    }

    /// Takes the rig's bodies in: a known name gets its new markers, a new name is appended.
    /// True when anything changed.
    pub fn merge(&mut self, rig: &[BodyDef]) -> bool {
        let mut changed = false;
        for b in rig {
            match self.defs.iter_mut().find(|d| d.name == b.name) {
                Some(d) if d.markers_m == b.markers_m => {}
                Some(d) => {
                    d.markers_m = b.markers_m.clone();
                    changed = true;
                }
                None => {
                    self.defs.push(b.clone());
                    changed = true;
                }
            }
        }
        changed
    }

    pub fn defs(&self) -> &[BodyDef] {
        &self.defs
    }

    pub fn names(&self) -> Vec<String> {
        self.defs.iter().map(|d| d.name.clone()).collect()
    }

    pub fn index(&self, name: &str) -> Option<usize> {
        self.defs.iter().position(|d| d.name == name)
    }

    pub fn name(&self, index: usize) -> &str {
        self.defs.get(index).map_or("", |d| d.name.as_str())
    }
}

impl VrFeedService {
    /// Takes the rig file's bodies and models when it changed and loads: VRPN describes the new
    /// trackers to its clients, NatNet and Qualisys RT answer with the new definitions, ROS 2
    /// and LSL are opened again with them; smoothing and prediction follow the new `[[body]]`
    /// tables. A file that does not load changes nothing and says why in health.
    pub(crate) fn apply_rig_changes(&mut self) {
        let Some(change) = self.watch.as_mut().and_then(|w| w.poll(&self.cfg.ctx.rig)) else {
            return;
        };
        let (rig, others_changed) = match change {
            Change::Refused(e) => {
                tracing::warn!("the rig file changed but does not load; nothing applied: {e}");
                self.node
                    .counters
                    .set_error(&format!("rig file changed, not applied: {e}"));
                return;
            }
            Change::Apply {
                rig,
                others_changed,
            } => (rig, others_changed),
        };
        let settings = match stereoscope_rig::vr::settings(&rig.spec) {
            Ok(Some(s)) => s,
            Ok(None) => {
                let m = "rig file changed: it has no [vr] now; restart the rig to stop the feed";
                tracing::warn!("{m}; its bodies are not applied");
                self.node.counters.set_error(m);
                return;
            }
            Err(e) => {
                tracing::warn!("the rig file changed but its [vr] does not load: {e}");
                self.node
                    .counters
                    .set_error(&format!("rig file changed, not applied: {e}"));
                return;
            }
        };
        // The addresses and frames stay as the feed started (a change there needs a restart);
        // which bodies go where follows the new rig.
        if let (Some(old), Some(new)) = (self.settings.vmt.as_mut(), settings.vmt) {
            old.2 = new.2;
        }
        if let (Some(old), Some(new)) = (self.settings.opentrack.as_mut(), settings.opentrack) {
            old.2 = new.2;
        }
        self.filters = settings
            .bodies
            .iter()
            .map(|b| b.smoothing.map(PoseFilter::new))
            .collect();
        self.settings.bodies = settings.bodies;
        self.rig_names = rig.spec.bodies.iter().map(|b| b.name.clone()).collect();
        let bodies_changed = self.defs.bodies.merge(&body_defs(&rig.spec));
        let trees: Vec<ros2::ModelTree> = rig
            .models
            .iter()
            .map(|m| ros2::ModelTree::of(&m.model))
            .collect();
        let models_changed = trees != self.defs.model_trees;
        self.defs.model_trees = trees;
        if bodies_changed && let Some(s) = self.vrpn.as_mut() {
            s.set_senders(&self.defs.bodies.names());
        }
        for l in &mut self.labs {
            let Some(s) = l.server.as_mut() else {
                continue;
            };
            let in_place = !bodies_changed || s.set_bodies(self.defs.bodies.defs());
            if !in_place || (models_changed && l.carries_models) {
                tracing::info!("{} opened again with the changed bodies and models", l.name);
                l.server = None;
                l.next_bind = std::time::Instant::now();
            }
        }
        self.reloads += 1;
        let c = &mut self.node.counters;
        c.set(Detail::Bodies, self.rig_names.join(","));
        c.set(Detail::RigReloads, self.reloads);
        tracing::info!(
            "bodies [{}] from the changed rig file applied (the feed's table: {:?})",
            self.rig_names.join(", "),
            self.defs.bodies.names()
        );
        if others_changed {
            tracing::warn!(
                "the rig file changed beyond [[body]] and [[model]]: restart the rig to apply the rest"
            );
            c.set_error(
                "rig file changed beyond [[body]] and [[model]]: restart to apply the rest",
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(name: &str, x: f64) -> BodyDef {
        BodyDef {
            name: name.into(),
            markers_m: vec![Point3::new(x, 0.0, 0.0), Point3::new(0.0, 0.1, 0.0)],
        }
    }

    /// A body keeps its index through every change: markers changed in place, new bodies
    /// appended, removed ones kept, the rig's new order ignored.
    #[test]
    fn a_body_keeps_its_index_while_the_feed_runs() {
        let mut t = BodyTable::new(&[body("head", 0.1), body("wand", 0.2)]);
        assert_eq!(t.names(), ["head", "wand"]);
        assert!(
            !t.merge(&[body("head", 0.1), body("wand", 0.2)]),
            "no change"
        );
        // Reordered, one changed, one added, none removed.
        assert!(t.merge(&[body("prop", 0.3), body("wand", 0.25), body("head", 0.1)]));
        assert_eq!(t.names(), ["head", "wand", "prop"]);
        assert_eq!(t.defs()[1].markers_m[0].x, 0.25);
        // Head taken out of the rig: it keeps index 0.
        assert!(!t.merge(&[body("wand", 0.25), body("prop", 0.3)]));
        assert_eq!(t.index("head"), Some(0));
        assert_eq!(t.index("prop"), Some(2));
        assert_eq!(t.name(2), "prop");
        assert_eq!(t.name(9), "");
        // From no body at all.
        let mut e = BodyTable::new(&[]);
        assert!(e.names().is_empty());
        assert!(e.merge(&[body("head", 0.1)]));
        assert_eq!(e.index("head"), Some(0));
    }
}
