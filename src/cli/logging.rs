//! The log every command writes to standard error.
//!
//! By default isin's own crates log at INFO — what a user needs: slaves
//! joining and dying, clients and the jobs they bring — and everything else
//! (winit, quinn, rustls, actix…) only at WARN; per-frame and per-pass lines
//! are DEBUG. `RUST_LOG` replaces that filter whole (`RUST_LOG=debug`, or
//! `RUST_LOG=info,isin_cluster=debug`). Colours only on a terminal, and never
//! with `NO_COLOR` set (<https://no-color.org>).

use tracing_subscriber::EnvFilter;

/// isin's own crates: logged at INFO by default.
const OWN_CRATES: &[&str] = &[
    "isin",
    "isin_actors",
    "isin_cluster",
    "isin_fuzzing",
    "isin_lab",
    "isin_tracer",
    "isin_transport",
    "isin_transport_quic",
    "isin_transport_tcp",
    "isin_transport_tls",
    "isin_viewer",
];

/// The filter without `RUST_LOG`: WARN, and INFO for isin's own crates.
fn default_filter() -> String {
    let mut filter = String::from("warn");
    for name in OWN_CRATES {
        filter.push_str(&format!(",{name}=info"));
    }
    filter
}

/// Whether to colour the log: on a terminal, unless `NO_COLOR` is set to
/// anything but the empty string.
fn colour(terminal: bool, no_color: Option<&std::ffi::OsStr>) -> bool {
    terminal && no_color.is_none_or(|v| v.is_empty())
}

/// Installs the subscriber (once; later calls do nothing).
pub fn init() {
    let filter = match std::env::var("RUST_LOG") {
        Ok(spec) if !spec.trim().is_empty() => EnvFilter::try_new(&spec).unwrap_or_else(|e| {
            eprintln!("isin: RUST_LOG={spec:?} is not a log filter ({e}); logging with the default");
            EnvFilter::new(default_filter())
        }),
        _ => EnvFilter::new(default_filter()),
    };
    let terminal = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let ansi = colour(terminal, std::env::var_os("NO_COLOR").as_deref());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(ansi)
        .with_writer(std::io::stderr)
        .try_init();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_color_turns_colours_off_on_a_terminal() {
        assert!(colour(true, None));
        assert!(!colour(true, Some("1".as_ref())));
        // Set but empty does not count (no-color.org).
        assert!(colour(true, Some("".as_ref())));
        assert!(!colour(false, None));
    }

    #[test]
    fn the_default_filter_names_every_workspace_crate() {
        let filter = default_filter();
        assert!(filter.starts_with("warn,"));
        // Every crate of the workspace is one of ours.
        // Cargo runs a package's tests in the package's folder: the workspace root.
        let crates = std::path::Path::new("crates");
        for entry in std::fs::read_dir(crates).unwrap() {
            let name = format!("isin_{}", entry.unwrap().file_name().to_string_lossy().replace('-', "_"));
            assert!(
                filter.contains(&format!(",{name}=info")),
                "{name} is not in the default filter {filter}"
            );
        }
        EnvFilter::try_new(&filter).expect("the default filter parses");
    }
}
