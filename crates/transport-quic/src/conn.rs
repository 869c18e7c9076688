//! One QUIC connection behind the transport interface's [`Connection`].
//!
//! Four tasks per connection:
//! - the **writer** takes frames from the [`FrameSender`] queue in order and
//!   puts [ordered](Delivery::Ordered) ones on the control stream and
//!   [independent](Delivery::Independent) ones each on a new unidirectional
//!   stream (see [`crate::wire`]), as the sender chose — or every frame on the
//!   control stream with [`QuicOptions::single_stream`];
//! - the **control reader** parses the peer's control stream;
//! - the **acceptor** accepts the peer's frame streams and reads each in its
//!   own task, admitting the announced length (the connection's maximum frame,
//!   then its memory budget) before reading the body, and the body under the
//!   connection's frame timeout (the control reader does the same);
//! - the **sequencer** merges both, delivering a frame once everything it
//!   depends on has been delivered, and ends the [`FrameReceiver`]'s stream.
//!
//! Closing. A direction ends with an end record on the control stream, which
//! tells the peer how many frame streams to expect. The QUIC connection itself
//! is closed once this side's data is all *acknowledged* (quinn keeps received
//! stream data readable after a close, so nothing acknowledged is lost) and the
//! reading side is done: the peer's end record was read, or the local side
//! stopped reading ([`FrameSender::close`] closes both directions; a dropped
//! [`FrameReceiver`] means nobody reads). A peer that vanishes is noticed by
//! the idle timeout; its receiver then ends like a closed one (`None`), as a
//! TCP peer killed by a signal would.

use crate::config::QuicOptions;
use crate::stats::Registry;
use crate::wire;
use isin_transport::{
    ConnShared, Connection, Delivery, FrameReceiver, FrameSender, Incoming, Outgoing, Reservation,
    TransportError,
};
use quinn::{ConnectionError, ReadError, RecvStream, SendStream, VarInt};
use std::collections::{BTreeMap, VecDeque};
use std::io;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio::task::JoinSet;

/// Application close code: both directions ended normally.
pub const CLOSE_DONE: u32 = 0;
/// Application close code: the peer broke the framing.
pub const CLOSE_PROTOCOL: u32 = 1;
/// Application close code: the peer sent a frame above the limit.
pub const CLOSE_TOO_LARGE: u32 = 2;
/// Application close code: the peer's frame did not fit the memory budget.
pub const CLOSE_OVER_BUDGET: u32 = 3;
/// Application close code: the peer did not complete a frame in time.
pub const CLOSE_FRAME_TIMEOUT: u32 = 4;

/// Frames buffered between the sequencer and the consumer.
const INBOUND_QUEUE: usize = 64;
/// Read-ahead events from the control reader and the acceptor.
const EVENT_QUEUE: usize = 64;
/// Bytes of ordered frames held back (waiting for an earlier independent
/// frame) before the sequencer stops reading the control stream. That stream's
/// unread data then waits in its own flow-control window, which is smaller than
/// the connection's, so frame streams keep arriving: no deadlock.
const MAX_PENDING_BYTES: usize = 64 << 20;
/// Independent frames held back (waiting for an ordered frame) beyond this:
/// the peer is flooding, not lagging, and the connection is closed. Frame
/// streams are never left unread instead — unread streams would hold the
/// connection's flow-control window, and the ordered frame they wait for could
/// then not arrive.
const MAX_WAITING_BYTES: usize = 256 << 20;
/// Largest allocation made ahead of the bytes actually arriving.
const PREALLOC: usize = 1 << 20;

/// A frame read and the budget it holds until the application takes it.
type Frame = (Vec<u8>, Reservation);

/// What the control reader found.
enum Ctrl {
    Frame { indep_before: u64, frame: Frame },
    End { indep_total: u64 },
    Failed(TransportError, u32),
    Lost(String),
}

/// What the acceptor found.
enum Indep {
    Frame { ordered_before: u64, frame: Frame },
    Failed(TransportError, u32),
    NoMore,
}

/// Wraps an established connection and its control stream halves, under the
/// limits of `shared`. `endpoint` is kept alive (and drained on close) for
/// client connections, which own theirs.
pub fn spawn(
    conn: quinn::Connection,
    control_send: SendStream,
    control_recv: RecvStream,
    endpoint: Option<quinn::Endpoint>,
    shared: Arc<ConnShared>,
    opts: &QuicOptions,
    registry: Arc<Registry>,
) -> Connection {
    registry.add(&conn);
    let peer = conn.remote_address().to_string();
    let (out_tx, out_rx) = mpsc::unbounded_channel();
    let (in_tx, in_rx) = mpsc::channel(INBOUND_QUEUE);
    let (ctrl_tx, ctrl_rx) = mpsc::channel(EVENT_QUEUE);
    let (indep_tx, indep_rx) = mpsc::channel(EVENT_QUEUE);
    tokio::spawn(control_reader(control_recv, shared.clone(), ctrl_tx));
    tokio::spawn(acceptor(conn.clone(), shared.clone(), indep_tx));
    let (linger, single_stream) = (opts.linger, opts.single_stream);
    let s = shared.clone();
    let p = peer.clone();
    tokio::spawn(async move {
        let writer = write_loop(&conn, control_send, out_rx, &s, single_stream, linger);
        let reader = sequence(&conn, ctrl_rx, indep_rx, in_tx, &s);
        let (wrote, read) = tokio::join!(writer, reader);
        tracing::debug!(peer = %p, ?wrote, ?read, "QUIC connection done");
        conn.close(VarInt::from_u32(CLOSE_DONE), b"done");
        registry.remove(&conn);
        if let Some(ep) = endpoint {
            // Let the close reach the peer before the socket goes.
            let _ = tokio::time::timeout(Duration::from_secs(1), ep.wait_idle()).await;
        }
    });
    Connection { peer, sender: FrameSender::new(out_tx, shared), receiver: FrameReceiver::new(in_rx) }
}

/// How the writer ended.
#[derive(Debug)]
enum Wrote {
    /// Everything sent and acknowledged, end record included.
    Flushed,
    /// The connection went away first.
    Lost,
    /// The peer did not acknowledge within the linger time.
    Abandoned,
}

async fn write_loop(
    conn: &quinn::Connection,
    mut control: SendStream,
    mut rx: mpsc::UnboundedReceiver<Outgoing>,
    shared: &Arc<ConnShared>,
    single_stream: bool,
    linger: Duration,
) -> Wrote {
    let closed = conn.closed();
    tokio::pin!(closed);
    let (mut ordered, mut indep) = (0u64, 0u64);
    let mut inflight: JoinSet<()> = JoinSet::new();
    loop {
        let item = tokio::select! {
            biased;
            _ = &mut closed => return Wrote::Lost,
            item = rx.recv() => item,
        };
        let (frame, delivery) = match item {
            Some(Outgoing::Frame(f, _)) if single_stream => (f, Delivery::Ordered),
            Some(Outgoing::Frame(f, d)) => (f, d),
            Some(Outgoing::Close) | None => break,
        };
        let Ok(len) = u32::try_from(frame.len()) else {
            tracing::error!(len = frame.len(), "frame too long for the wire; dropped");
            continue;
        };
        match delivery {
            Delivery::Independent => {
                let Ok(mut stream) = conn.open_uni().await else { return Wrote::Lost };
                let header = wire::stream_header(ordered, len);
                indep += 1;
                shared.count_sent((wire::STREAM_HEADER + frame.len()) as u64);
                inflight.spawn(async move {
                    if stream.write_all(&header).await.is_ok() && stream.write_all(&frame).await.is_ok() {
                        let _ = stream.finish();
                        // Resolves once the peer acknowledged everything (or stopped the stream).
                        let _ = stream.stopped().await;
                    }
                });
                while inflight.try_join_next().is_some() {}
            }
            Delivery::Ordered => {
                let header = wire::control_header(indep, len);
                if control.write_all(&header).await.is_err() || control.write_all(&frame).await.is_err() {
                    return Wrote::Lost;
                }
                ordered += 1;
                shared.count_sent((wire::CONTROL_HEADER + frame.len()) as u64);
            }
        }
    }
    // Graceful end of this direction: end record, then wait until the peer
    // holds every byte, so closing the connection loses nothing.
    let flush = async {
        if control.write_all(&wire::end_record(indep)).await.is_err() {
            return Wrote::Lost;
        }
        let _ = control.finish();
        while inflight.join_next().await.is_some() {}
        match control.stopped().await {
            Ok(None) => Wrote::Flushed,
            _ => Wrote::Lost,
        }
    };
    tokio::time::timeout(linger, flush).await.unwrap_or(Wrote::Abandoned)
}

/// How the reading side ended.
#[derive(Debug)]
enum Read {
    /// The peer's end record and every frame it announced were delivered.
    Ended,
    /// The local side closed the connection or dropped the receiver.
    Stopped,
    /// The connection was lost before the peer's end record.
    Lost,
    /// The peer broke the rules; the connection was closed with an error.
    Failed,
}

/// Frames waiting for their turn (see [`crate::wire`] for the rules).
#[derive(Default)]
struct Sequencer {
    ordered_done: u64,
    indep_done: u64,
    /// Control frames in stream order, with the independent count each awaits.
    ordered: VecDeque<(u64, Frame)>,
    /// Independent frames keyed by the ordered count each awaits.
    waiting: BTreeMap<u64, Vec<Frame>>,
    ordered_bytes: usize,
    waiting_bytes: usize,
    end: Option<u64>,
    no_more_streams: bool,
}

impl Sequencer {
    fn push_ordered(&mut self, indep_before: u64, frame: Frame) {
        self.ordered_bytes += frame.0.len();
        self.ordered.push_back((indep_before, frame));
    }

    fn push_indep(&mut self, ordered_before: u64, frame: Frame) {
        self.waiting_bytes += frame.0.len();
        self.waiting.entry(ordered_before).or_default().push(frame);
    }

    /// The next frame that may be delivered now.
    fn pop(&mut self) -> Option<Frame> {
        if let Some(mut entry) = self.waiting.first_entry()
            && *entry.key() <= self.ordered_done
        {
            let frame = entry.get_mut().pop();
            if entry.get().is_empty() {
                entry.remove();
            }
            let frame = frame?;
            self.indep_done += 1;
            self.waiting_bytes -= frame.0.len();
            return Some(frame);
        }
        if self.ordered.front().is_some_and(|(before, _)| *before <= self.indep_done) {
            let (_, frame) = self.ordered.pop_front()?;
            self.ordered_done += 1;
            self.ordered_bytes -= frame.0.len();
            return Some(frame);
        }
        None
    }

    /// Whether to read the control stream now. Past the limit, the queue's head
    /// waits for an independent frame, which more control frames cannot supply.
    fn want_ordered(&self) -> bool {
        self.end.is_none() && self.ordered_bytes < MAX_PENDING_BYTES
    }

    /// Whether to take frame streams now: always, until there are no more
    /// (see [`MAX_WAITING_BYTES`]).
    fn want_independent(&self) -> bool {
        !self.no_more_streams
    }

    /// `Some(Ok)` once the peer's direction ended cleanly, `Some(Err)` if it
    /// can no longer end cleanly.
    fn finished(&self) -> Option<Result<(), String>> {
        if self.waiting_bytes > MAX_WAITING_BYTES {
            return Some(Err(format!("peer sent {} bytes of frames out of order", self.waiting_bytes)));
        }
        let total = self.end?;
        if self.ordered.is_empty() && self.waiting.is_empty() && self.indep_done >= total {
            return Some(Ok(()));
        }
        if self.ordered.is_empty()
            && self.waiting.first_key_value().is_some_and(|(k, _)| *k > self.ordered_done)
        {
            return Some(Err("a frame stream depends on control frames the peer never sent".into()));
        }
        if self.no_more_streams {
            let missing = total.saturating_sub(self.indep_done);
            return Some(Err(format!("peer announced {missing} more frame streams than it sent")));
        }
        None
    }
}

async fn sequence(
    conn: &quinn::Connection,
    mut ctrl_rx: mpsc::Receiver<Ctrl>,
    mut indep_rx: mpsc::Receiver<Indep>,
    tx: mpsc::Sender<Incoming>,
    shared: &Arc<ConnShared>,
) -> Read {
    let mut seq = Sequencer::default();
    let fail = |err: TransportError, code: u32| {
        let tx = tx.clone();
        async move {
            tracing::warn!(peer = %conn.remote_address(), "closing QUIC connection: {err}");
            conn.close(VarInt::from_u32(code), err.to_string().as_bytes());
            let _ = tx.send(Err(err)).await;
            Read::Failed
        }
    };
    loop {
        while let Some(frame) = seq.pop() {
            if shared.is_closed() {
                return Read::Stopped;
            }
            if tx.send(Ok(frame)).await.is_err() {
                return Read::Stopped;
            }
        }
        match seq.finished() {
            Some(Ok(())) => return Read::Ended,
            Some(Err(e)) => {
                return fail(io::Error::new(io::ErrorKind::InvalidData, e).into(), CLOSE_PROTOCOL).await;
            }
            None => {}
        }
        if shared.is_closed() {
            return Read::Stopped;
        }
        tokio::select! {
            biased;
            _ = shared.close_notify.notified() => return Read::Stopped,
            _ = tx.closed() => return Read::Stopped,
            ev = ctrl_rx.recv(), if seq.want_ordered() => match ev {
                Some(Ctrl::Frame { indep_before, frame }) => seq.push_ordered(indep_before, frame),
                Some(Ctrl::End { indep_total }) => seq.end = Some(indep_total),
                Some(Ctrl::Failed(err, code)) => return fail(err, code).await,
                Some(Ctrl::Lost(why)) => {
                    tracing::info!(peer = %conn.remote_address(), "QUIC connection lost: {why}");
                    return Read::Lost;
                }
                None => return Read::Lost,
            },
            ev = indep_rx.recv(), if seq.want_independent() => match ev {
                Some(Indep::Frame { ordered_before, frame }) => seq.push_indep(ordered_before, frame),
                Some(Indep::Failed(err, code)) => return fail(err, code).await,
                Some(Indep::NoMore) | None => seq.no_more_streams = true,
            },
        }
    }
}

/// Why reading a stream stopped early.
enum ReadFail {
    /// The stream ended `got` bytes into a record.
    Truncated,
    /// The connection went away.
    Lost(ConnectionError),
    /// The peer reset the stream, or quinn refused the read.
    Other(String),
}

impl From<ReadError> for ReadFail {
    fn from(e: ReadError) -> Self {
        match e {
            ReadError::ConnectionLost(c) => ReadFail::Lost(c),
            other => ReadFail::Other(other.to_string()),
        }
    }
}

/// Fills `buf`; `Ok(false)` on a clean end of stream before its first byte.
async fn read_full(recv: &mut RecvStream, buf: &mut [u8]) -> Result<bool, ReadFail> {
    let mut got = 0;
    while got < buf.len() {
        match recv.read(&mut buf[got..]).await? {
            Some(n) => got += n,
            None if got == 0 => return Ok(false),
            None => return Err(ReadFail::Truncated),
        }
    }
    Ok(true)
}

/// Reads exactly `len` bytes, allocating as they arrive (never more than
/// [`PREALLOC`] ahead), so an announced length costs nothing until sent.
async fn read_body(recv: &mut RecvStream, len: usize) -> Result<Vec<u8>, ReadFail> {
    let mut buf = Vec::with_capacity(len.min(PREALLOC));
    while buf.len() < len {
        match recv.read_chunk(len - buf.len(), true).await? {
            Some(chunk) => buf.extend_from_slice(&chunk.bytes),
            None => return Err(ReadFail::Truncated),
        }
    }
    Ok(buf)
}

/// Admits a frame of `len` announced bytes ([`ConnShared::admit`]), or the
/// error and close code refusing it.
fn admit(len: u32, shared: &ConnShared) -> Result<Reservation, (TransportError, u32)> {
    shared.admit(len as u64).map_err(|e| {
        let code = match e {
            TransportError::OverBudget { .. } => CLOSE_OVER_BUDGET,
            _ => CLOSE_TOO_LARGE,
        };
        (e, code)
    })
}

/// [`read_body`] within the connection's frame timeout: `Ok(Err)` if the peer
/// was too slow.
async fn read_body_in_time(
    recv: &mut RecvStream,
    len: usize,
    shared: &ConnShared,
) -> Result<Result<Vec<u8>, (TransportError, u32)>, ReadFail> {
    let timeout = shared.frame_timeout();
    match tokio::time::timeout(timeout, read_body(recv, len)).await {
        Ok(body) => Ok(Ok(body?)),
        Err(_) => Ok(Err((TransportError::FrameTimeout { len: len as u64, timeout }, CLOSE_FRAME_TIMEOUT))),
    }
}

fn invalid(what: &str) -> TransportError {
    io::Error::new(io::ErrorKind::InvalidData, what.to_string()).into()
}

async fn control_reader(mut recv: RecvStream, shared: Arc<ConnShared>, tx: mpsc::Sender<Ctrl>) {
    let event = loop {
        let mut tag = [0u8; 1];
        let r = match read_full(&mut recv, &mut tag).await {
            Ok(true) => match tag[0] {
                wire::TAG_FRAME => read_control_frame(&mut recv, &shared).await,
                wire::TAG_END => {
                    let mut total = [0u8; 8];
                    match read_full(&mut recv, &mut total).await {
                        Ok(true) => {
                            let indep_total = u64::from_be_bytes(total);
                            let _ = tx.send(Ctrl::End { indep_total }).await;
                            // Read up to the stream's end, so dropping it does not ask
                            // the peer to stop sending.
                            let _ = recv.read_chunk(1, true).await;
                            return;
                        }
                        Ok(false) => Err(ReadFail::Truncated),
                        Err(e) => Err(e),
                    }
                }
                other => {
                    break Ctrl::Failed(invalid(&format!("unknown control record {other}")), CLOSE_PROTOCOL);
                }
            },
            Ok(false) => {
                break Ctrl::Failed(invalid("control stream ended without an end record"), CLOSE_PROTOCOL);
            }
            Err(e) => Err(e),
        };
        match r {
            Ok(Ok(ev)) => {
                if tx.send(ev).await.is_err() {
                    return;
                }
            }
            Ok(Err((err, code))) => break Ctrl::Failed(err, code),
            Err(ReadFail::Truncated) => {
                break Ctrl::Failed(io::Error::from(io::ErrorKind::UnexpectedEof).into(), CLOSE_PROTOCOL);
            }
            Err(ReadFail::Lost(c)) => break Ctrl::Lost(c.to_string()),
            Err(ReadFail::Other(why)) => break Ctrl::Failed(invalid(&why), CLOSE_PROTOCOL),
        }
    };
    let _ = tx.send(event).await;
}

/// One frame record after its tag: `Ok(Err)` for a violation found before reading the body.
async fn read_control_frame(
    recv: &mut RecvStream,
    shared: &ConnShared,
) -> Result<Result<Ctrl, (TransportError, u32)>, ReadFail> {
    let mut h = [0u8; wire::CONTROL_HEADER - 1];
    if !read_full(recv, &mut h).await? {
        return Err(ReadFail::Truncated);
    }
    let mut before = [0u8; 8];
    before.copy_from_slice(&h[..8]);
    let mut len = [0u8; 4];
    len.copy_from_slice(&h[8..]);
    let len = u32::from_be_bytes(len);
    // Limit and budget first; only then the bytes.
    let reservation = match admit(len, shared) {
        Ok(r) => r,
        Err(refused) => return Ok(Err(refused)),
    };
    let data = match read_body_in_time(recv, len as usize, shared).await? {
        Ok(data) => data,
        Err(late) => return Ok(Err(late)),
    };
    shared.count_received((wire::CONTROL_HEADER + data.len()) as u64);
    Ok(Ok(Ctrl::Frame { indep_before: u64::from_be_bytes(before), frame: (data, reservation) }))
}

async fn acceptor(conn: quinn::Connection, shared: Arc<ConnShared>, tx: mpsc::Sender<Indep>) {
    let mut readers: JoinSet<Option<Indep>> = JoinSet::new();
    loop {
        tokio::select! {
            s = conn.accept_uni() => match s {
                Ok(recv) => {
                    readers.spawn(read_frame_stream(recv, shared.clone()));
                }
                Err(_) => break,
            },
            Some(done) = readers.join_next() => {
                if let Ok(Some(ev)) = done && tx.send(ev).await.is_err() {
                    return;
                }
            }
        }
    }
    // Streams already received stay readable after the connection closed.
    while let Some(done) = readers.join_next().await {
        if let Ok(Some(ev)) = done
            && tx.send(ev).await.is_err()
        {
            return;
        }
    }
    let _ = tx.send(Indep::NoMore).await;
}

/// Reads one frame stream; `None` if the connection went away meanwhile.
async fn read_frame_stream(mut recv: RecvStream, shared: Arc<ConnShared>) -> Option<Indep> {
    let r = async {
        let mut h = [0u8; wire::STREAM_HEADER];
        if !read_full(&mut recv, &mut h).await? {
            return Err(ReadFail::Truncated);
        }
        let (ordered_before, len) = wire::parse_stream_header(&h);
        // Limit and budget first; only then the bytes.
        let reservation = match admit(len, &shared) {
            Ok(r) => r,
            Err((err, code)) => return Ok(Indep::Failed(err, code)),
        };
        let data = match read_body_in_time(&mut recv, len as usize, &shared).await? {
            Ok(data) => data,
            Err((err, code)) => return Ok(Indep::Failed(err, code)),
        };
        // The stream must end right after the frame.
        if recv.read_chunk(1, true).await?.is_some() {
            return Ok(Indep::Failed(invalid("bytes after the frame on a frame stream"), CLOSE_PROTOCOL));
        }
        shared.count_received((wire::STREAM_HEADER + data.len()) as u64);
        Ok(Indep::Frame { ordered_before, frame: (data, reservation) })
    };
    match r.await {
        Ok(ev) => Some(ev),
        Err(ReadFail::Lost(_)) => None,
        Err(ReadFail::Truncated) => {
            Some(Indep::Failed(io::Error::from(io::ErrorKind::UnexpectedEof).into(), CLOSE_PROTOCOL))
        }
        Err(ReadFail::Other(why)) => Some(Indep::Failed(invalid(&why), CLOSE_PROTOCOL)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(bytes: &[u8]) -> Frame {
        (bytes.to_vec(), Reservation::unbudgeted(bytes.len()))
    }

    fn pop(s: &mut Sequencer) -> Option<Vec<u8>> {
        s.pop().map(|(data, _)| data)
    }

    #[test]
    fn frames_wait_exactly_for_what_was_sent_before_them() {
        let mut s = Sequencer::default();
        // Sent: I0, O0 (after 1 independent), I1 (after 1 ordered), I2 (after 1 ordered).
        s.push_indep(1, f(b"I1"));
        s.push_ordered(1, f(b"O0"));
        assert_eq!(pop(&mut s), None, "O0 waits for I0, I1 waits for O0");
        assert!(s.want_independent() && s.want_ordered());
        s.push_indep(0, f(b"I0"));
        assert_eq!(pop(&mut s).as_deref(), Some(&b"I0"[..]));
        assert_eq!(pop(&mut s).as_deref(), Some(&b"O0"[..]));
        assert_eq!(pop(&mut s).as_deref(), Some(&b"I1"[..]));
        assert_eq!(pop(&mut s), None);
        s.end = Some(3);
        assert_eq!(s.finished(), None, "I2 announced but not here yet");
        s.push_indep(1, f(b"I2"));
        assert_eq!(pop(&mut s).as_deref(), Some(&b"I2"[..]));
        assert_eq!(s.finished(), Some(Ok(())));
        assert_eq!((s.ordered_bytes, s.waiting_bytes), (0, 0));
    }

    #[test]
    fn reading_stops_only_where_it_cannot_help() {
        let mut s = Sequencer::default();
        // A huge ordered frame waiting for a tile sent before it: keep taking
        // streams (the tile is among them), stop reading the control stream.
        s.push_ordered(1, f(&vec![0; MAX_PENDING_BYTES]));
        assert!(!s.want_ordered());
        assert!(s.want_independent());
        // Tiles waiting for an ordered frame not read yet: keep reading both.
        let mut s = Sequencer::default();
        s.push_indep(1, f(&vec![0; MAX_PENDING_BYTES]));
        assert!(s.want_ordered());
        assert!(s.want_independent());
    }

    #[test]
    fn a_peer_that_lies_about_its_frames_is_caught() {
        let s = Sequencer { end: Some(2), no_more_streams: true, ..Sequencer::default() };
        assert!(matches!(s.finished(), Some(Err(_))));
        let mut s = Sequencer::default();
        s.push_indep(5, f(&[1]));
        s.end = Some(1);
        assert!(matches!(s.finished(), Some(Err(_))), "depends on ordered frames never sent");
        let mut s = Sequencer::default();
        s.push_ordered(1, f(&[]));
        s.push_indep(9, f(&vec![0; MAX_WAITING_BYTES + 1]));
        assert!(matches!(s.finished(), Some(Err(_))), "flood");
    }
}
