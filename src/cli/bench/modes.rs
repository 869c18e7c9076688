//! The transport and compression modes the benches run, in one place.
//!
//! Compression is negotiated at join by `isin master --compression MODE`.
//! The bench passes `--compression` only for modes other than the master's
//! default, so it also runs against a master without the flag (raw only).

/// Transports a master can listen with (`isin master --transport`).
pub const TRANSPORTS: &[&str] = &["tcp", "quic"];

/// Every compression mode the benches know (`isin master --compression`).
pub const COMPRESSIONS: &[&str] = &["raw", "auto"];

/// What a master does without `--compression`.
pub const DEFAULT_COMPRESSION: &str = "raw";

/// Whether `isin master` has a `--compression` flag in this build. While it
/// does not, only [`DEFAULT_COMPRESSION`] can be measured.
pub const MASTER_HAS_COMPRESSION_FLAG: bool = false;

/// Modes run when none are asked for: every mode this build can measure.
pub fn default_compressions() -> Vec<String> {
    COMPRESSIONS
        .iter()
        .filter(|&&c| MASTER_HAS_COMPRESSION_FLAG || c == DEFAULT_COMPRESSION)
        .map(|c| c.to_string())
        .collect()
}

/// Checks a list of transports.
pub fn check_transports(list: &[String]) -> anyhow::Result<()> {
    for t in list {
        anyhow::ensure!(TRANSPORTS.contains(&t.as_str()), "unknown transport `{t}` (known: {TRANSPORTS:?})");
    }
    Ok(())
}

/// Checks a list of compression modes against what this build can run.
pub fn check_compressions(list: &[String]) -> anyhow::Result<()> {
    for c in list {
        anyhow::ensure!(
            COMPRESSIONS.contains(&c.as_str()),
            "unknown compression `{c}` (known: {COMPRESSIONS:?})"
        );
        anyhow::ensure!(
            MASTER_HAS_COMPRESSION_FLAG || c == DEFAULT_COMPRESSION,
            "compression `{c}` needs `isin master --compression`, which this build lacks"
        );
    }
    Ok(())
}

/// Extra `isin master` arguments for a transport and a compression mode.
pub fn master_args(transport: &str, compression: &str) -> Vec<String> {
    let mut args = vec!["--transport".to_string(), transport.to_string()];
    if compression != DEFAULT_COMPRESSION {
        args.extend(["--compression".to_string(), compression.to_string()]);
    }
    args
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_compression_adds_no_flag_and_others_do() {
        assert!(!master_args("tcp", DEFAULT_COMPRESSION).contains(&"--compression".to_string()));
        let other = COMPRESSIONS.iter().find(|&&c| c != DEFAULT_COMPRESSION).unwrap();
        assert_eq!(master_args("quic", other)[2..], ["--compression".to_string(), other.to_string()]);
    }

    #[test]
    fn only_runnable_modes_are_defaults_and_unknown_ones_are_refused() {
        let d = default_compressions();
        assert!(d.contains(&DEFAULT_COMPRESSION.to_string()));
        assert!(check_compressions(&d).is_ok());
        assert!(check_compressions(&["zip".into()]).is_err());
        assert!(check_transports(&["udp".into()]).is_err());
        assert!(check_transports(&TRANSPORTS.iter().map(|t| t.to_string()).collect::<Vec<_>>()).is_ok());
    }
}
