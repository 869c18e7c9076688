//! A client of the `tev` image viewer's IPC protocol, to show a render's
//! tiles as they finish (`isin render --tev HOST:PORT`).
//!
//! tev listens on TCP (127.0.0.1:14158 by default). Every packet is a
//! little-endian `u32` length — of the whole packet, these four bytes
//! included — then a type byte and the fields: strings NUL-terminated,
//! integers little-endian. isin sends two packets:
//!
//! * `CreateImage` (type 4): `grab_focus: u8`, `name`, `width: i32`,
//!   `height: i32`, `channel_count: i32`, then the channel names;
//! * `UpdateImage` (type 6, version 3 of that packet): `grab_focus: u8`,
//!   `name`, `channel_count: i32`, the channel names, `x, y, width, height:
//!   i32`, one `i64` offset and then one `i64` stride per channel (in
//!   floats), then the `f32` samples: isin interleaves them per pixel, so
//!   channel `c`'s offset is `c` and every stride the channel count.

use crate::outputs::{self, Pass};
use anyhow::Context;
use isin_tracer::{FrameBuffers, Tile};
use std::io::Write;
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::mpsc;
use std::time::Duration;

/// Packet type of `CreateImage`.
pub const CREATE_IMAGE: u8 = 4;
/// Packet type of `UpdateImage`, version 3 (channel offsets and strides).
pub const UPDATE_IMAGE_V3: u8 = 6;

/// How long to try to reach tev before giving up.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// A packet being built: its length is filled in by [`Packet::finish`].
struct Packet(Vec<u8>);

impl Packet {
    fn new(kind: u8) -> Self {
        let mut b = vec![0; 4];
        b.push(kind);
        Packet(b)
    }
    fn u8(&mut self, v: u8) -> &mut Self {
        self.0.push(v);
        self
    }
    fn i32(&mut self, v: i32) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn i64(&mut self, v: i64) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn str(&mut self, s: &str) -> &mut Self {
        // A NUL inside would end the string early: tev would misread the rest.
        self.0.extend(s.bytes().filter(|&b| b != 0));
        self.0.push(0);
        self
    }
    fn finish(mut self) -> anyhow::Result<Vec<u8>> {
        let len = u32::try_from(self.0.len()).context("tev packet over 4 GiB")?;
        self.0[..4].copy_from_slice(&len.to_le_bytes());
        Ok(self.0)
    }
}

/// A `CreateImage` packet: a black `width × height` image named `name` with
/// `channels`, shown at once.
pub fn create_image(name: &str, width: u32, height: u32, channels: &[String]) -> anyhow::Result<Vec<u8>> {
    let mut p = Packet::new(CREATE_IMAGE);
    p.u8(1).str(name).i32(side(width)?).i32(side(height)?).i32(count(channels.len())?);
    for c in channels {
        p.str(c);
    }
    p.finish()
}

/// An `UpdateImage` packet: the `w × h` block at `(x, y)` of image `name`,
/// `samples` holding `channels.len()` floats per pixel, row-major.
pub fn update_image(
    name: &str,
    channels: &[String],
    (x, y, w, h): (u32, u32, u32, u32),
    samples: &[f32],
) -> anyhow::Result<Vec<u8>> {
    let n = channels.len();
    anyhow::ensure!(
        samples.len() == w as usize * h as usize * n,
        "tev tile: {} samples for {w}×{h} pixels of {n} channels",
        samples.len()
    );
    let mut p = Packet::new(UPDATE_IMAGE_V3);
    p.u8(0).str(name).i32(count(n)?);
    for c in channels {
        p.str(c);
    }
    p.i32(side(x)?).i32(side(y)?).i32(side(w)?).i32(side(h)?);
    for c in 0..n {
        p.i64(c as i64);
    }
    for _ in 0..n {
        p.i64(n as i64);
    }
    p.0.reserve(samples.len() * 4);
    for s in samples {
        p.0.extend(s.to_le_bytes());
    }
    p.finish()
}

fn side(v: u32) -> anyhow::Result<i32> {
    i32::try_from(v).context("image side beyond tev's i32")
}

fn count(v: usize) -> anyhow::Result<i32> {
    i32::try_from(v).context("too many channels for tev")
}

/// A connection to tev whose packets are written by a thread of its own, so
/// that rendering never waits on the network. If tev goes away the render
/// goes on: the first failure is logged and later packets are dropped.
pub struct TevStream {
    tx: Option<mpsc::Sender<Vec<u8>>>,
    writer: Option<std::thread::JoinHandle<()>>,
}

impl TevStream {
    /// Connects to tev at `addr` (`HOST:PORT`).
    pub fn connect(addr: &str) -> anyhow::Result<TevStream> {
        let hint = "is tev running? It listens on 127.0.0.1:14158 unless started with --hostname";
        let addrs: Vec<_> = addr
            .to_socket_addrs()
            .with_context(|| format!("--tev {addr}: not a HOST:PORT address"))?
            .collect();
        let mut last = None;
        let mut stream = None;
        for a in &addrs {
            match TcpStream::connect_timeout(a, CONNECT_TIMEOUT) {
                Ok(s) => {
                    stream = Some(s);
                    break;
                }
                Err(e) => last = Some(e),
            }
        }
        let mut stream = match (stream, last) {
            (Some(s), _) => s,
            (None, Some(e)) => {
                return Err(e).with_context(|| format!("cannot connect to tev at {addr} ({hint})"));
            }
            (None, None) => anyhow::bail!("--tev {addr}: the name resolves to no address"),
        };
        let _ = stream.set_nodelay(true);
        let (tx, rx) = mpsc::channel::<Vec<u8>>();
        let name = addr.to_owned();
        let writer = std::thread::Builder::new()
            .name("tev".into())
            .spawn(move || {
                for packet in rx {
                    if let Err(e) = stream.write_all(&packet) {
                        tracing::warn!("tev at {name} stopped taking tiles ({e}); the render goes on");
                        return;
                    }
                }
                let _ = stream.flush();
            })
            .context("cannot start the tev thread")?;
        Ok(TevStream { tx: Some(tx), writer: Some(writer) })
    }

    /// Queues a packet.
    fn send(&self, packet: Vec<u8>) {
        if let Some(tx) = &self.tx {
            // Fails only once the writer has given up, which it has logged.
            let _ = tx.send(packet);
        }
    }

    /// Creates a `width × height` image `name` in tev with the beauty's
    /// channels and those of `passes` ([`outputs::channel_names`]), for
    /// [`TevImage::send_tile`] to fill.
    pub fn create_image(
        self,
        name: &str,
        width: u32,
        height: u32,
        passes: &[Pass],
    ) -> anyhow::Result<TevImage> {
        let channels = outputs::channel_names(passes);
        self.send(create_image(name, width, height, &channels)?);
        Ok(TevImage { stream: self, name: name.to_owned(), passes: passes.to_vec(), channels })
    }

    /// Waits until every queued packet is written (or the writer gave up).
    pub fn close(mut self) {
        self.shut();
    }

    fn shut(&mut self) {
        self.tx = None;
        if let Some(w) = self.writer.take() {
            let _ = w.join();
        }
    }
}

/// An image created in tev, filled tile by tile (from any thread).
pub struct TevImage {
    stream: TevStream,
    name: String,
    passes: Vec<Pass>,
    channels: Vec<String>,
}

impl TevImage {
    /// Queues `tile`'s pixels, `buffers` as [`isin_tracer::render::render_tile_hdr`]
    /// made them (with the image's passes).
    pub fn send_tile(&self, tile: Tile, buffers: &FrameBuffers) {
        let mut samples = Vec::with_capacity(tile.pixel_count() * self.channels.len());
        for i in 0..tile.pixel_count() {
            outputs::channel_values(buffers, &self.passes, i, &mut samples);
        }
        match update_image(&self.name, &self.channels, (tile.x, tile.y, tile.w, tile.h), &samples) {
            Ok(packet) => self.stream.send(packet),
            Err(e) => tracing::warn!("tile not sent to tev: {e:#}"),
        }
    }

    /// Waits until every queued tile is written (or the connection failed).
    pub fn close(self) {
        self.stream.close();
    }
}

impl Drop for TevStream {
    fn drop(&mut self) {
        self.shut();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_carry_their_whole_length_and_the_fields_in_order() {
        let names = vec!["R".to_string(), "depth.Z".to_string()];
        let p = create_image("a", 3, 2, &names).unwrap();
        assert_eq!(u32::from_le_bytes(p[..4].try_into().unwrap()) as usize, p.len());
        let mut want = vec![CREATE_IMAGE, 1, b'a', 0];
        for v in [3i32, 2, 2] {
            want.extend(v.to_le_bytes());
        }
        want.extend(b"R\0depth.Z\0");
        assert_eq!(&p[4..], &want[..]);

        let u = update_image("a", &names, (1, 0, 1, 2), &[1.0, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(u32::from_le_bytes(u[..4].try_into().unwrap()) as usize, u.len());
        assert_eq!(&u[4..8], &[UPDATE_IMAGE_V3, 0, b'a', 0]);
        // Header, names, four i32, two offsets and two strides, four floats.
        assert_eq!(u.len(), 8 + 4 + 10 + 16 + 32 + 16);
        assert_eq!(&u[u.len() - 4..], &4.0f32.to_le_bytes());
        assert!(update_image("a", &names, (0, 0, 2, 2), &[0.0; 4]).is_err());
    }
}
