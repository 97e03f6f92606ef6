//! Messages one service sends another to put something right (`docs/protocol.md`,
//! "Liveliness"). Checked like every other message before they are acted on.

use super::{Checked, Checker};
use serde::{Deserialize, Serialize};

/// A request that a service declare its liveliness token again: sent by a launcher whose
/// router hears the service's health reports but holds no liveliness token for it (a router
/// can lose another PC's tokens while their owner runs, `docs/reliability.md`). The service
/// withdraws its token and declares it anew, which every router passes on again.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TokenRenewal {
    pub schema: u32,
    pub rig: String,
    /// The service asked: its host and name ("capture/cam0").
    pub host: String,
    pub service: String,
    /// The PC whose router lacks the token.
    pub asked_by: String,
    /// How long that router has lacked it while the service's reports arrived, in seconds.
    pub missing_s: f64,
}

impl TokenRenewal {
    pub(super) fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.name("host", &self.host)?;
        c.name("service", &self.service)?;
        c.name("asked_by", &self.asked_by)?;
        c.range("missing_s", self.missing_s, 0.0, f64::MAX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::{DecodeError, Message, SCHEMA_VERSION};

    /// A renewal reads back as written; one naming no service, or with a negative or endless
    /// time, is refused by field.
    #[test]
    fn a_renewal_request_is_checked_by_field() {
        let r = TokenRenewal {
            schema: SCHEMA_VERSION,
            rig: "lab".into(),
            host: "capture2".into(),
            service: "moments/cam2".into(),
            asked_by: "fusion".into(),
            missing_s: 3.2,
        };
        assert_eq!(TokenRenewal::from_json(&r.to_json()).unwrap(), r);
        let field = |r: &TokenRenewal| match TokenRenewal::from_json(&r.to_json()) {
            Err(DecodeError::Invalid { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        let mut bad = r.clone();
        bad.service.clear();
        assert_eq!(field(&bad), "service");
        let mut bad = r.clone();
        bad.missing_s = -1.0;
        assert_eq!(field(&bad), "missing_s");
        // JSON has no infinity: an endless time cannot even be written as one.
        let text = String::from_utf8(r.to_json())
            .unwrap()
            .replace("3.2", "1e999");
        assert!(TokenRenewal::from_json(text.as_bytes()).is_err());
        let mut other = serde_json::to_value(&r).unwrap();
        other["schema"] = serde_json::json!(SCHEMA_VERSION + 1);
        assert!(matches!(
            TokenRenewal::from_json(other.to_string().as_bytes()),
            Err(DecodeError::Schema { .. })
        ));
    }
}
