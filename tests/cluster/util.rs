//! Test harness: real `isin` processes on loopback, their output read line by
//! line so tests wait on what a process says (never on sleeps), and a guard
//! that kills every process a test started, even when the test fails.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// How long any single wait may take before the test fails.
pub const TIMEOUT: Duration = Duration::from_secs(60);

/// The transports a cluster test runs over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transport {
    /// `--transport tcp`: TLS over TCP.
    Tcp,
    /// `--transport tcp --insecure`: plaintext TCP.
    TcpInsecure,
    /// `--transport quic`.
    Quic,
}

impl Transport {
    /// Its name in join tickets (and in the viewer's status).
    pub fn name(self) -> &'static str {
        match self {
            Transport::Tcp => "tcp",
            Transport::TcpInsecure => "tcp-insecure",
            Transport::Quic => "quic",
        }
    }

    /// The master arguments that select it.
    pub fn master_args(self) -> &'static [&'static str] {
        match self {
            Transport::Tcp => &["--transport", "tcp"],
            Transport::TcpInsecure => &["--transport", "tcp", "--insecure"],
            Transport::Quic => &["--transport", "quic"],
        }
    }

    /// The scheme of the tickets a master on it prints.
    pub fn scheme(self) -> &'static str {
        match self {
            Transport::Tcp => "isin://",
            Transport::TcpInsecure => "isin+tcp-insecure://",
            Transport::Quic => "isin+quic://",
        }
    }

    /// For a master that must start after its slaves: the extra master
    /// arguments that fix its identity in `dir`, and the join ticket for
    /// `token` at `addr` that the master will print.
    pub fn prepared_ticket(self, dir: &Path, token: &str, addr: &str) -> (Vec<String>, String) {
        let scheme = self.scheme();
        if self == Transport::TcpInsecure {
            return (Vec::new(), format!("{scheme}{token}@{addr}"));
        }
        let id = isin_transport_tls::Identity::generate().expect("identity");
        std::fs::write(dir.join("cert.der"), id.cert_der().as_ref()).expect("cert");
        std::fs::write(dir.join("key.der"), id.key_der().secret_pkcs8_der()).expect("key");
        let args = vec!["--identity".to_string(), dir.display().to_string()];
        (args, format!("{scheme}{token}@{addr}?fp={}", id.fingerprint()))
    }

    /// A loopback address whose port was free a moment ago (for a master that
    /// must start after its slaves).
    pub fn free_addr(self) -> String {
        let port = match self {
            Transport::Tcp | Transport::TcpInsecure => {
                std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
            }
            Transport::Quic => std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port(),
        };
        format!("127.0.0.1:{port}")
    }
}

/// A peer that writes raw bytes at the master, below the protocol: the
/// transport's own framing is up to the test (plaintext TCP), or whole
/// transport frames whose content is up to the test (TLS over TCP and QUIC,
/// whose framing sits under TLS).
pub enum RawPeer {
    /// A plain TCP connection.
    Tcp(std::net::TcpStream),
    /// A TLS/TCP or QUIC connection that passed TLS (it knows the ticket's
    /// fingerprint) but not the token handshake.
    Framed(tokio::runtime::Runtime, isin_transport::Connection),
}

/// A client of `c`'s transport, pinned to its certificate (for peers the
/// test drives itself).
pub fn client_transport(c: &Cluster) -> Box<dyn isin_transport::Transport> {
    if c.transport == Transport::TcpInsecure {
        return Box::new(isin_transport_tcp::TcpTransport::insecure());
    }
    let ticket: isin_transport::Ticket = c.ticket.parse().expect("ticket");
    let fp = ticket.fingerprint.expect("an encrypted ticket carries a fingerprint");
    match c.transport {
        Transport::Quic => Box::new(isin_transport_quic::QuicTransport::client(fp).expect("client")),
        _ => Box::new(isin_transport_tcp::TcpTransport::client(fp).expect("client")),
    }
}

impl RawPeer {
    /// Connects to the master of `c`.
    pub fn connect(c: &Cluster) -> RawPeer {
        if c.transport == Transport::TcpInsecure {
            return RawPeer::Tcp(std::net::TcpStream::connect(&c.addr).expect("connect"));
        }
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
        let conn = rt.block_on(async { client_transport(c).connect(&c.addr).await.expect("connect") });
        RawPeer::Framed(rt, conn)
    }

    /// Sends `bytes` (TCP: raw on the stream; QUIC: as one frame) and asserts
    /// that the master then closes the connection having sent at most its
    /// (small) challenge.
    pub fn send_then_expect_close(self, bytes: &[u8]) {
        use std::io::{Read, Write};
        match self {
            RawPeer::Tcp(mut s) => {
                s.set_read_timeout(Some(TIMEOUT)).unwrap();
                // The master may close before reading everything: a failed write is fine.
                let _ = s.write_all(bytes);
                let mut buf = Vec::new();
                match s.read_to_end(&mut buf) {
                    Ok(_) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => {}
                    Err(e) => panic!("the master did not close the connection: {e}"),
                }
                assert!(buf.len() < 1024, "master sent {} bytes to an unauthenticated peer", buf.len());
            }
            RawPeer::Framed(rt, mut conn) => rt.block_on(async move {
                let _ = conn.sender.send(bytes.to_vec());
                let mut received = 0;
                loop {
                    match tokio::time::timeout(TIMEOUT, conn.receiver.recv()).await {
                        Ok(Some(Ok(frame))) => received += frame.len(),
                        Ok(Some(Err(_)) | None) => break,
                        Err(_) => panic!("the master did not close the connection"),
                    }
                }
                assert!(received < 1024, "master sent {received} bytes to an unauthenticated peer");
            }),
        }
    }

    /// Announces a frame far longer than the master accepts before a peer has
    /// authenticated (plaintext TCP: a 4 GiB − 1 length prefix; TLS and QUIC:
    /// a 1 MiB frame) and asserts the master closes the connection.
    pub fn send_oversized_then_expect_close(self) {
        match self {
            RawPeer::Tcp(_) => self.send_then_expect_close(&u32::MAX.to_be_bytes()),
            RawPeer::Framed(..) => self.send_then_expect_close(&vec![0x5a; 1 << 20]),
        }
    }

    /// Sends `payload` as one well-framed frame and expects the close.
    pub fn send_frame_then_expect_close(self, payload: &[u8]) {
        match self {
            RawPeer::Tcp(_) => {
                let framed = [&(payload.len() as u32).to_be_bytes()[..], payload].concat();
                self.send_then_expect_close(&framed)
            }
            RawPeer::Framed(..) => self.send_then_expect_close(payload),
        }
    }
}

/// Which output stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stream {
    /// Standard output (results, tickets).
    Out,
    /// Standard error (logs).
    Err,
}

#[derive(Default)]
struct Lines {
    out: Vec<String>,
    err: Vec<String>,
    closed: u8,
}

/// A running `isin` process; killed (SIGKILL) and reaped on drop.
pub struct Proc {
    /// Label for failure messages.
    pub name: String,
    child: Child,
    lines: Arc<(Mutex<Lines>, Condvar)>,
}

impl Proc {
    /// Starts `isin ARGS…` with logs at `log` level.
    pub fn spawn(name: &str, args: &[&str], log: &str) -> Proc {
        Self::spawn_in(name, Path::new("."), args, log)
    }

    /// [`Proc::spawn`] in working directory `dir`.
    pub fn spawn_in(name: &str, dir: &Path, args: &[&str], log: &str) -> Proc {
        Self::spawn_with_env(name, dir, args, log, &[])
    }

    /// [`Proc::spawn_in`] with the environment variables `env` set; an
    /// empty `log` leaves `RUST_LOG` unset (isin's default levels).
    pub fn spawn_with_env(name: &str, dir: &Path, args: &[&str], log: &str, env: &[(&str, &str)]) -> Proc {
        let mut command = Command::new(env!("CARGO_BIN_EXE_isin"));
        match log {
            "" => command.env_remove("RUST_LOG"),
            log => command.env("RUST_LOG", log),
        };
        let mut child = command
            .current_dir(dir)
            .args(args)
            // No ticket from the environment the tests run in.
            .env_remove("ISIN_TICKET")
            .env_remove("ISIN_TOKEN")
            .envs(env.iter().copied())
            .env("RUST_BACKTRACE", "0")
            // Headless: `isin` with no arguments must not try to open a window.
            .env_remove("DISPLAY")
            .env_remove("WAYLAND_DISPLAY")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        let lines: Arc<(Mutex<Lines>, Condvar)> = Arc::default();
        let out = child.stdout.take().expect("piped");
        let err = child.stderr.take().expect("piped");
        for (stream, pipe) in
            [(Stream::Out, Box::new(out) as Box<dyn std::io::Read + Send>), (Stream::Err, Box::new(err))]
        {
            let lines = lines.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(pipe).lines() {
                    let Ok(line) = line else { break };
                    let (m, cv) = &*lines;
                    let mut l = m.lock().unwrap();
                    match stream {
                        Stream::Out => l.out.push(line),
                        Stream::Err => l.err.push(line),
                    }
                    cv.notify_all();
                }
                let (m, cv) = &*lines;
                m.lock().unwrap().closed += 1;
                cv.notify_all();
            });
        }
        Proc { name: name.to_string(), child, lines }
    }

    /// Everything the process printed so far, for failure messages.
    pub fn dump(&self) -> String {
        let l = self.lines.0.lock().unwrap();
        format!(
            "--- {} stdout:\n{}\n--- {} stderr:\n{}",
            self.name,
            l.out.join("\n"),
            self.name,
            l.err.join("\n")
        )
    }

    /// Lines of `stream` matching `pred`, so far.
    pub fn matching(&self, stream: Stream, pred: impl Fn(&str) -> bool) -> Vec<String> {
        let l = self.lines.0.lock().unwrap();
        let v = if stream == Stream::Out { &l.out } else { &l.err };
        v.iter().filter(|s| pred(s)).cloned().collect()
    }

    /// Waits until `stream` has `n` lines containing `needle`; returns the n-th.
    pub fn wait_for_n(&self, stream: Stream, needle: &str, n: usize) -> String {
        let deadline = Instant::now() + TIMEOUT;
        let (m, cv) = &*self.lines;
        let mut l = m.lock().unwrap();
        loop {
            let v = if stream == Stream::Out { &l.out } else { &l.err };
            let hits: Vec<&String> = v.iter().filter(|s| s.contains(needle)).collect();
            if hits.len() >= n {
                return hits[n - 1].clone();
            }
            let now = Instant::now();
            if now >= deadline || l.closed == 2 {
                drop(l);
                panic!("{} never printed {n}× `{needle}`\n{}", self.name, self.dump());
            }
            l = cv.wait_timeout(l, deadline - now).unwrap().0;
        }
    }

    /// Waits for one line containing `needle`.
    pub fn wait_for(&self, stream: Stream, needle: &str) -> String {
        self.wait_for_n(stream, needle, 1)
    }

    /// Waits for the process to exit (both pipes closed, then reaped).
    pub fn wait_exit(&mut self) -> ExitStatus {
        let deadline = Instant::now() + TIMEOUT;
        {
            let (m, cv) = &*self.lines;
            let mut l = m.lock().unwrap();
            while l.closed < 2 {
                let now = Instant::now();
                if now >= deadline {
                    drop(l);
                    panic!("{} did not exit within {TIMEOUT:?}\n{}", self.name, self.dump());
                }
                l = cv.wait_timeout(l, deadline - now).unwrap().0;
            }
        }
        self.child.wait().expect("reap")
    }

    /// `kill -9`.
    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The repository root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The scene the cluster tests render: the shipped paper scene (its textures
/// and meshes travel to the slaves in the scene bundle).
pub fn scene() -> PathBuf {
    root().join("scenes/paper.toml")
}

/// A master and its slaves, all separate processes.
pub struct Cluster {
    /// `isin master`.
    pub master: Proc,
    /// `isin slave` processes, in start order.
    pub slaves: Vec<Proc>,
    /// The join ticket the master printed.
    pub ticket: String,
    /// The master's address.
    pub addr: String,
    /// Transport in use.
    pub transport: Transport,
    /// Scratch directory for output images.
    pub dir: tempfile::TempDir,
}

impl Cluster {
    /// Starts a master on a free loopback port and `slaves` one-thread slaves,
    /// and waits until they have joined.
    pub fn start(transport: Transport, slaves: usize, master_args: &[&str]) -> Cluster {
        let scene = scene();
        let mut args = vec!["master", scene.to_str().unwrap(), "--listen", "127.0.0.1:0"];
        args.extend_from_slice(transport.master_args());
        args.extend_from_slice(master_args);
        let master = Proc::spawn("master", &args, "info,isin_cluster::cluster=debug");
        let ticket = master.wait_for(Stream::Out, "ticket ").trim_start_matches("ticket ").trim().to_string();
        assert!(ticket.starts_with(transport.scheme()), "{transport:?} master printed {ticket}");
        let addr =
            master.wait_for(Stream::Out, "listening ").trim_start_matches("listening ").trim().to_string();
        let mut c = Cluster {
            master,
            slaves: Vec::new(),
            ticket,
            addr,
            transport,
            dir: tempfile::tempdir().expect("temp dir"),
        };
        for i in 0..slaves {
            c.add_slave(&format!("s{i}"));
        }
        c.wait_joined(slaves);
        c
    }

    /// Starts one more slave (one render thread) named `name`; does not wait.
    pub fn add_slave(&mut self, name: &str) -> usize {
        let p = Proc::spawn(
            name,
            &["slave", "--connect", &self.ticket, "--threads", "1", "--name", name],
            "info",
        );
        self.slaves.push(p);
        self.slaves.len() - 1
    }

    /// Waits until the master has logged `n` slaves joining in all.
    pub fn wait_joined(&self, n: usize) {
        if n > 0 {
            self.master.wait_for_n(Stream::Err, "joined with", n);
        }
    }

    /// Starts `isin render --connect` writing `name`; the caller waits on it.
    pub fn render_async(&self, name: &str, extra: &[&str]) -> (Proc, PathBuf) {
        let out = self.dir.path().join(name);
        let scene = scene();
        let mut args =
            vec!["render", scene.to_str().unwrap(), "--connect", &self.ticket, "-o", out.to_str().unwrap()];
        args.extend_from_slice(extra);
        let args: Vec<String> = args.into_iter().map(String::from).collect();
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        (Proc::spawn("render --connect", &refs, "info"), out)
    }

    /// The master's ticket with its token replaced by `token`.
    pub fn ticket_with_token(&self, token: &str) -> String {
        let mut t: isin_transport::Ticket = self.ticket.parse().expect("ticket");
        t.token = token.to_string();
        t.to_string()
    }

    /// One frame through the cluster: its pixels and what `isin render` printed.
    pub fn render(&self, name: &str, extra: &[&str]) -> (Vec<u8>, String) {
        let (mut p, out) = self.render_async(name, extra);
        let status = p.wait_exit();
        assert!(status.success(), "cluster render failed\n{}\n{}", p.dump(), self.master.dump());
        let stdout = p.matching(Stream::Out, |_| true).join("\n");
        (pixels(&out), stdout)
    }
}

/// `isin render` of the test scene on this machine, for comparison.
pub fn render_local(extra: &[&str]) -> Vec<u8> {
    render_local_of(&scene(), extra)
}

/// `isin render` of `scene` on this machine.
pub fn render_local_of(scene: &Path, extra: &[&str]) -> Vec<u8> {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("local.png");
    let mut args = vec!["render", scene.to_str().unwrap(), "--quiet", "-o", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let mut p = Proc::spawn("render", &args, "warn");
    assert!(p.wait_exit().success(), "local render failed\n{}", p.dump());
    pixels(&out)
}

/// The RGB8 pixels of a PNG file.
pub fn pixels(path: &Path) -> Vec<u8> {
    image::open(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display())).to_rgb8().into_raw()
}

/// Asserts two images are byte-identical, reporting the first difference.
pub fn assert_same_pixels(a: &[u8], b: &[u8], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: different sizes");
    if let Some(i) = a.iter().zip(b).position(|(x, y)| x != y) {
        let n = a.iter().zip(b).filter(|(x, y)| x != y).count();
        panic!("{what}: {n} bytes differ, first at byte {i}");
    }
}
