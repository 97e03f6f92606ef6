//! How a service's process ends, so that its supervisor can tell a mistake in the rig (which
//! no restart mends) from a crash (which a restart may).

use std::process::ExitCode;
use stereoscope_rig::RigError;

/// The exit status of a service that refused its configuration (sysexits' `EX_CONFIG`): the
/// launcher does not restart it.
pub const CONFIG_EXIT_STATUS: u8 = 78;

/// Whether `e` or any error beneath it is a [`RigError`].
pub fn is_config_error(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cur = Some(e);
    while let Some(c) = cur {
        if c.is::<RigError>() {
            return true;
        }
        cur = c.source();
    }
    false
}

/// A service's `main`: prints an error with its causes and exits with
/// [`CONFIG_EXIT_STATUS`] for a configuration error, 1 for any other.
pub fn exit_code(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            if e.chain().any(is_config_error) {
                ExitCode::from(CONFIG_EXIT_STATUS)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("service failed")]
    struct Wrapper(#[source] RigError);

    #[test]
    fn a_rig_error_anywhere_in_the_chain_is_a_configuration_error() {
        let rig = stereoscope_rig::error::err(
            "camera[0].moments.max_objects",
            "0 is not between 1 and 64",
        );
        assert!(is_config_error(&Wrapper(rig.clone())));
        let wrapped = anyhow::Error::new(rig).context("starting moments/cam0");
        assert!(wrapped.chain().any(is_config_error));
        let other = anyhow::anyhow!("iceoryx2 said no");
        assert!(!other.chain().any(is_config_error));
    }
}
