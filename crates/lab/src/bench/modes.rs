//! The transport and compression modes the benches run, in one place.
//!
//! Compression is negotiated at join by `isin master --compression MODE`; the
//! bench always passes the mode explicitly.

use isin_cluster::codec::Codec;

/// Transports a master can listen with: `tcp` (TLS over TCP), `quic`, and
/// `tcp-insecure` (plaintext TCP, `isin master --transport tcp --insecure`).
pub const TRANSPORTS: &[&str] = &["tcp", "quic", "tcp-insecure"];

/// Every compression mode the benches know (`isin master --compression`).
pub const COMPRESSIONS: &[&str] = &["raw", "auto", "lz4", "qoi"];

/// Modes run when none are asked for: tiles as they are, and the codec the
/// master picks by default.
pub fn default_compressions() -> Vec<String> {
    ["raw", "auto"].iter().map(|c| c.to_string()).collect()
}

/// Checks a list of transports.
pub fn check_transports(list: &[String]) -> anyhow::Result<()> {
    for t in list {
        anyhow::ensure!(TRANSPORTS.contains(&t.as_str()), "unknown transport `{t}` (known: {TRANSPORTS:?})");
    }
    Ok(())
}

/// Checks a list of compression modes.
pub fn check_compressions(list: &[String]) -> anyhow::Result<()> {
    for c in list {
        anyhow::ensure!(
            COMPRESSIONS.contains(&c.as_str()),
            "unknown compression `{c}` (known: {COMPRESSIONS:?})"
        );
    }
    Ok(())
}

/// A transport in plain words, for plots.
pub fn transport_name(transport: &str) -> String {
    match transport {
        "tcp" => "TLS over TCP",
        "quic" => "QUIC",
        "tcp-insecure" => "plain TCP",
        other => other,
    }
    .to_string()
}

/// What travels under a compression mode, in plain words, for plots: `auto`
/// is named by the codec the master picks first ([`Codec::ALL`]), which
/// every slave of this build offers.
pub fn compression_name(compression: &str) -> String {
    match compression {
        "raw" => "raw tiles".to_string(),
        "auto" => format!("{} tiles", Codec::ALL[0].name().to_uppercase()),
        other => format!("{} tiles", other.to_uppercase()),
    }
}

/// Extra `isin master` arguments for a transport and a compression mode.
pub fn master_args(transport: &str, compression: &str) -> Vec<String> {
    let mut args = match transport {
        "tcp-insecure" => vec!["--transport".into(), "tcp".into(), "--insecure".into()],
        t => vec!["--transport".to_string(), t.to_string()],
    };
    args.extend(["--compression".to_string(), compression.to_string()]);
    args
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn master_args_name_the_transport_and_the_compression() {
        assert_eq!(master_args("quic", "qoi"), ["--transport", "quic", "--compression", "qoi"]);
        assert_eq!(
            master_args("tcp-insecure", "raw"),
            ["--transport", "tcp", "--insecure", "--compression", "raw"]
        );
    }

    #[test]
    fn modes_have_plain_names() {
        assert_eq!(transport_name("tcp"), "TLS over TCP");
        assert_eq!(transport_name("tcp-insecure"), "plain TCP");
        assert_eq!(compression_name("raw"), "raw tiles");
        assert_eq!(compression_name("auto"), "QOI tiles");
        assert_eq!(compression_name("lz4"), "LZ4 tiles");
    }

    #[test]
    fn defaults_are_known_and_unknown_modes_are_refused() {
        let d = default_compressions();
        assert!(d.contains(&"raw".to_string()) && d.contains(&"auto".to_string()));
        assert!(check_compressions(&d).is_ok());
        assert!(check_compressions(&["zip".into()]).is_err());
        assert!(check_transports(&["udp".into()]).is_err());
        assert!(check_transports(&TRANSPORTS.iter().map(|t| t.to_string()).collect::<Vec<_>>()).is_ok());
    }
}
