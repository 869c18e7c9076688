//! `isin bench master` on a small cluster: the whole master over the
//! in-memory transport routes tiles, finds both sets of vanished slaves dead
//! no sooner than its heartbeat timeout, and while the simulated slaves
//! "render" it routes no more than their threads can answer at that pace.

use std::process::Command;

#[test]
fn the_master_bench_measures_both_vanishings_and_paces_the_rendering_slaves() {
    let dir = tempfile::tempdir().unwrap();
    let (slaves, threads, render_ms, timeout_ms) = (20u64, 2u64, 10u64, 300u64);
    let out = Command::new(env!("CARGO_BIN_EXE_isin"))
        .args(["bench", "master", "--size", "320x240", "--seconds", "1", "--vanish", "3"])
        .args(["--slaves", &slaves.to_string(), "--threads", &threads.to_string()])
        .args(["--render-ms", &render_ms.to_string(), "--heartbeat-timeout-ms", &timeout_ms.to_string()])
        .arg("--out-dir")
        .arg(dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "isin bench master failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("master.json")).unwrap()).unwrap();
    let number =
        |key: &str| report[key].as_f64().unwrap_or_else(|| panic!("{key} missing or null\n{report}"));
    assert!(number("routed_tiles") > 0.0, "{report}");
    // Dead only once silent for the timeout, by the master's clock; found
    // within three timeouts (null otherwise).
    for key in ["silence_at_death_ms", "rendering_silence_at_death_ms"] {
        assert!(number(key) >= timeout_ms as f64, "{key}: {report}");
    }
    for key in ["detect_ms", "rendering_detect_ms"] {
        assert!(number(key) < 3.0 * timeout_ms as f64, "{key}: {report}");
    }
    // Paced: each of the slaves' threads answers at most one tile per
    // `render_ms` (the vanished three of the first set no longer at all).
    let ceiling = (slaves * threads * 1000 / render_ms) as f64;
    let paced = number("rendering_per_second");
    assert!(paced > 0.0 && paced <= ceiling, "{paced} tiles/s against a ceiling of {ceiling}\n{report}");
    assert!(number("routed_per_second") > ceiling, "unpaced, the same slaves answer faster\n{report}");
}
