//! The chaos soak, a minute per transport: `isin bench chaos --seconds 60`
//! (a master, four slave PCs in the lab, a viewer and a batch job while
//! slaves and the master are killed and restarted, slaves stopped, their
//! cables unplugged, lossy and held) loses no frame, every frame is
//! byte-identical to a local render, every kind of fault was injected and
//! memory stays flat. It needs the lab (root, `ip netns`, `tc`, `nft`):
//! elsewhere it says it is skipped.

use std::process::Command;
use std::sync::Mutex;

/// The lab's namespaces have fixed names: one soak at a time.
static LAB: Mutex<()> = Mutex::new(());

fn soak(transport: &str, seed: u64) {
    let support = isin_lab::netlab::Support::probe();
    if let (Err(e), _) | (_, Err(e)) = (&support.netns, &support.loss) {
        println!("skipped: the chaos soak needs the lab ({e})");
        return;
    }
    let _one = LAB.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = isin_lab::netlab::PREFIX;
    if isin_lab::netlab::netns::list_namespaces().iter().any(|n| n.starts_with(prefix)) {
        println!("skipped: a lab (a running `isin bench`?) exists; building one would remove it");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let t0 = std::time::Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_isin"))
        .args(["bench", "chaos", "--seconds", "60", "--transport", transport, "--seed", &seed.to_string()])
        .arg("--out")
        .arg(dir.path())
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "isin bench chaos failed:\n{stdout}\n{stderr}");
    println!("{transport}: {:.1} s\n{stdout}", t0.elapsed().as_secs_f64());
    let text = std::fs::read_to_string(dir.path().join("chaos.json")).unwrap();
    let r: serde_json::Value = serde_json::from_str(&text).unwrap();
    let n = |v: &serde_json::Value| v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"));
    for client in ["viewer", "batch"] {
        let t = &r[client];
        assert!(n(&t["completed"]) > 0, "{client}: no frame completed\n{stdout}");
        assert_eq!(n(&t["lost"]), 0, "{client}: frames lost\n{stdout}");
        assert_eq!(n(&t["identical"]), n(&t["completed"]), "{client}: frames differ\n{stdout}");
        assert_eq!(n(&t["completed"]), n(&t["requested"]), "{client}\n{stdout}");
    }
    for kind in ["slave-kill", "slave-stop", "master-kill", "link-down", "loss", "delay-spike"] {
        assert!(r["fault_counts"][kind].as_u64().is_some_and(|c| c >= 1), "no {kind} injected\n{stdout}");
    }
    for f in r["faults"].as_array().unwrap() {
        assert!(f["error"].is_null(), "a fault failed: {f}");
    }
    for rec in r["recoveries"].as_array().unwrap() {
        assert!(rec["seconds"].is_number(), "no frame after a master restart: {rec}\n{stdout}");
    }
    assert_eq!(r["rss_flat"], true, "memory grew\n{stdout}");
}

#[test]
fn a_minute_of_chaos_over_tcp_loses_no_frame() {
    soak("tcp", 1);
}

#[test]
fn a_minute_of_chaos_over_quic_loses_no_frame() {
    soak("quic", 2);
}
