//! A UDP relay on loopback between one client and a server, which can drop a
//! fraction of the datagrams (deterministic pseudo-random) or go silent
//! altogether — a peer that vanished without a word, as a killed process or a
//! pulled cable would.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use tokio::net::UdpSocket;

/// A running relay; dropping it stops it.
pub struct Relay {
    /// Where clients should send (the relay's front).
    pub addr: SocketAddr,
    #[allow(dead_code)] // the benchmark never silences its relay
    silent: Arc<AtomicBool>,
    /// Datagrams dropped so far.
    #[allow(dead_code)] // not every test crate reads the counters
    pub dropped: Arc<AtomicU64>,
    /// Datagrams forwarded so far.
    #[allow(dead_code)]
    pub forwarded: Arc<AtomicU64>,
    task: tokio::task::JoinHandle<()>,
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl Relay {
    /// Relays to `server`, dropping `loss_per_mille` of the datagrams each way.
    pub async fn start(server: SocketAddr, loss_per_mille: u64, seed: u64) -> Relay {
        let front = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let back = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        back.connect(server).await.unwrap();
        let addr = front.local_addr().unwrap();
        let silent = Arc::new(AtomicBool::new(false));
        let dropped = Arc::new(AtomicU64::new(0));
        let forwarded = Arc::new(AtomicU64::new(0));
        let (s, d, f) = (silent.clone(), dropped.clone(), forwarded.clone());
        let task = tokio::spawn(async move {
            let mut client: Option<SocketAddr> = None;
            let mut state = seed | 1;
            let mut a = vec![0u8; 65536];
            let mut b = vec![0u8; 65536];
            loop {
                let mut keep = || {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    state % 1000 >= loss_per_mille
                };
                tokio::select! {
                    r = front.recv_from(&mut a) => {
                        let Ok((n, from)) = r else { return };
                        client = Some(from);
                        if s.load(Ordering::Relaxed) || !keep() {
                            d.fetch_add(1, Ordering::Relaxed);
                        } else {
                            f.fetch_add(1, Ordering::Relaxed);
                            let _ = back.send(&a[..n]).await;
                        }
                    }
                    r = back.recv(&mut b) => {
                        let Ok(n) = r else { continue };
                        let Some(to) = client else { continue };
                        if s.load(Ordering::Relaxed) || !keep() {
                            d.fetch_add(1, Ordering::Relaxed);
                        } else {
                            f.fetch_add(1, Ordering::Relaxed);
                            let _ = front.send_to(&b[..n], to).await;
                        }
                    }
                }
            }
        });
        Relay { addr, silent, dropped, forwarded, task }
    }

    /// From now on, nothing gets through either way.
    #[allow(dead_code)]
    pub fn go_silent(&self) {
        self.silent.store(true, Ordering::Relaxed);
    }
}
