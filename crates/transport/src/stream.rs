//! Length-delimited frames over any byte stream: `[len: u32 big-endian][len bytes]`.
//!
//! [`spawn`] turns a reader and a writer into a [`Connection`] by running two
//! tokio tasks. The reader admits every announced length
//! ([`ConnShared::admit`]: the maximum frame, then the memory budget) *before*
//! allocating, and reads the body under the connection's frame timeout. A
//! frame refused or late ([`TransportError::FrameTooLarge`],
//! [`TransportError::OverBudget`], [`TransportError::FrameTimeout`]) or a
//! broken stream fails the connection: the error is the receiver's last item,
//! and the writer closes the stream. The writer batches: it writes every frame
//! already queued before flushing, so a burst of tiles costs one system call,
//! not one each.

use super::{
    ConnShared, Connection, FrameReceiver, FrameSender, Incoming, Outgoing, Reservation, TransportError,
};
use std::sync::Arc;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, BufWriter};
use tokio::sync::mpsc;

/// Frames buffered between the reader task and the consumer.
const INBOUND_QUEUE: usize = 64;

/// Runs the codec over `reader`/`writer` (e.g. the halves of a TCP stream),
/// accepting frames of at most `max_frame` bytes. Call inside a tokio runtime.
pub fn spawn<R, W>(reader: R, writer: W, peer: String, max_frame: usize) -> Connection
where
    R: AsyncRead + Unpin + Send + 'static,
    W: AsyncWrite + Unpin + Send + 'static,
{
    spawn_with(reader, writer, peer, ConnShared::new(max_frame), Counting::Frames)
}

/// Who counts a connection's bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Counting {
    /// The codec: each frame counts its length prefix and body.
    Frames,
    /// The layer below the codec (e.g. a socket wrapper under TLS, which sees
    /// records and handshakes the codec never does) adds bytes to the shared
    /// counters itself; the codec counts frames only.
    External,
}

/// [`spawn`] around counters the caller made (and may already have fed, e.g.
/// during a TLS handshake), counting bytes as `counting` says.
pub fn spawn_with<R, W>(
    reader: R,
    writer: W,
    peer: String,
    shared: Arc<ConnShared>,
    counting: Counting,
) -> Connection
where
    R: AsyncRead + Unpin + Send + 'static,
    W: AsyncWrite + Unpin + Send + 'static,
{
    let (out_tx, out_rx) = mpsc::unbounded_channel();
    let (in_tx, in_rx) = mpsc::channel(INBOUND_QUEUE);
    // The reader closes the writer when the connection fails; a weak handle,
    // so that dropping every FrameSender still ends the writer.
    let closer = out_tx.downgrade();
    tokio::spawn(write_loop(writer, out_rx, shared.clone(), counting));
    tokio::spawn(read_loop(reader, in_tx, closer, shared.clone(), counting));
    Connection { peer, sender: FrameSender::new(out_tx, shared), receiver: FrameReceiver::new(in_rx) }
}

async fn write_loop<W: AsyncWrite + Unpin>(
    writer: W,
    mut rx: mpsc::UnboundedReceiver<Outgoing>,
    shared: Arc<ConnShared>,
    counting: Counting,
) {
    let mut w = BufWriter::with_capacity(64 << 10, writer);
    'outer: while let Some(first) = rx.recv().await {
        let mut next = Some(first);
        while let Some(item) = next.take() {
            match item {
                Outgoing::Frame(frame, _) => {
                    let Ok(len) = u32::try_from(frame.len()) else {
                        tracing::error!(len = frame.len(), "frame too long for the wire; dropped");
                        continue;
                    };
                    if w.write_all(&len.to_be_bytes()).await.is_err() || w.write_all(&frame).await.is_err() {
                        break 'outer;
                    }
                    match counting {
                        Counting::Frames => shared.count_sent(4 + frame.len() as u64),
                        Counting::External => shared.count_frame_sent(),
                    }
                }
                Outgoing::Close => break 'outer,
            }
            next = rx.try_recv().ok();
        }
        if w.flush().await.is_err() {
            break;
        }
    }
    let _ = w.flush().await;
    let _ = w.shutdown().await;
}

async fn read_loop<R: AsyncRead + Unpin>(
    mut reader: R,
    tx: mpsc::Sender<Incoming>,
    closer: mpsc::WeakUnboundedSender<Outgoing>,
    shared: Arc<ConnShared>,
    counting: Counting,
) {
    loop {
        if shared.is_closed() {
            return;
        }
        let frame = tokio::select! {
            biased;
            _ = shared.close_notify.notified() => return,
            r = read_frame(&mut reader, &shared, counting) => r,
        };
        match frame {
            Ok(Some(f)) => {
                if tx.send(Ok(f)).await.is_err() {
                    return;
                }
            }
            Ok(None) => return,
            Err(e) => {
                tracing::info!("closing the connection: {e}");
                // Nothing more is read, so nothing more is sent: close now
                // (queued frames are still flushed first).
                if let Some(out) = closer.upgrade() {
                    let _ = out.send(Outgoing::Close);
                }
                shared.close();
                let _ = tx.send(Err(e)).await;
                return;
            }
        }
    }
}

/// One frame and its reservation, `None` on a clean end of stream between frames.
async fn read_frame<R: AsyncRead + Unpin>(
    reader: &mut R,
    shared: &ConnShared,
    counting: Counting,
) -> Result<Option<(Vec<u8>, Reservation)>, TransportError> {
    let mut len = [0u8; 4];
    let mut got = 0;
    while got < 4 {
        let n = match reader.read(&mut len[got..]).await {
            Ok(n) => n,
            // A peer that vanished between frames (killed, or a TLS peer whose
            // socket closed without close_notify) ends the stream as a FIN
            // does: frames are self-delimiting, so nothing was cut short.
            Err(e) if got == 0 && e.kind() == std::io::ErrorKind::UnexpectedEof => 0,
            Err(e) => return Err(e.into()),
        };
        if n == 0 {
            if got == 0 {
                return Ok(None);
            }
            return Err(std::io::Error::from(std::io::ErrorKind::UnexpectedEof).into());
        }
        got += n;
    }
    let len = u32::from_be_bytes(len) as u64;
    // Limit and budget first; only then the allocation.
    let reservation = shared.admit(len)?;
    let mut buf = vec![0u8; reservation.len()];
    let timeout = shared.frame_timeout();
    match tokio::time::timeout(timeout, reader.read_exact(&mut buf)).await {
        Ok(read) => read?,
        Err(_) => return Err(TransportError::FrameTimeout { len, timeout }),
    };
    match counting {
        Counting::Frames => shared.count_received(4 + len),
        Counting::External => shared.count_frame_received(),
    }
    Ok(Some((buf, reservation)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(max: usize) -> (Connection, tokio::io::DuplexStream) {
        let (a, b) = tokio::io::duplex(1 << 16);
        let (r, w) = tokio::io::split(a);
        (spawn(r, w, "test".into(), max), b)
    }

    #[tokio::test]
    async fn frames_round_trip_and_are_counted() {
        let (a, b) = tokio::io::duplex(1 << 16);
        let (ar, aw) = tokio::io::split(a);
        let (br, bw) = tokio::io::split(b);
        let mut x = spawn(ar, aw, "x".into(), 1024);
        let mut y = spawn(br, bw, "y".into(), 1024);
        for i in 0..100u8 {
            x.sender.send(vec![i; i as usize]).unwrap();
        }
        for i in 0..100u8 {
            assert_eq!(y.receiver.recv().await.unwrap().unwrap(), vec![i; i as usize]);
        }
        y.sender.send(b"back".to_vec()).unwrap();
        assert_eq!(x.receiver.recv().await.unwrap().unwrap(), b"back");
        let total: u64 = (0..100u64).map(|i| i + 4).sum();
        assert_eq!(y.sender.stats().bytes_received, total);
        assert_eq!(x.sender.stats().frames_sent, 100);
        // Closing one side ends the other's stream cleanly.
        x.sender.close();
        assert!(y.receiver.recv().await.is_none());
        assert!(x.sender.send(vec![1]).is_err());
    }

    #[tokio::test]
    async fn oversized_length_prefix_is_refused_without_reading_the_body() {
        let (mut conn, mut raw) = pair(1000);
        raw.write_all(&u32::MAX.to_be_bytes()).await.unwrap();
        match conn.receiver.recv().await {
            Some(Err(TransportError::FrameTooLarge { len, max })) => {
                assert_eq!((len, max), (u32::MAX as u64, 1000))
            }
            other => panic!("expected FrameTooLarge, got {other:?}"),
        }
        assert!(conn.receiver.recv().await.is_none());
    }

    #[tokio::test]
    async fn limit_can_be_raised_after_authentication() {
        let (mut conn, mut raw) = pair(10);
        conn.sender.set_max_frame(100);
        raw.write_all(&50u32.to_be_bytes()).await.unwrap();
        raw.write_all(&[7u8; 50]).await.unwrap();
        assert_eq!(conn.receiver.recv().await.unwrap().unwrap(), vec![7u8; 50]);
    }

    #[tokio::test]
    async fn truncated_frame_is_an_error_and_clean_eof_is_not() {
        let (mut conn, mut raw) = pair(100);
        raw.write_all(&10u32.to_be_bytes()).await.unwrap();
        raw.write_all(&[1, 2, 3]).await.unwrap();
        drop(raw);
        assert!(matches!(conn.receiver.recv().await, Some(Err(TransportError::Io(_)))));
        let (mut conn, raw) = pair(100);
        drop(raw);
        assert!(conn.receiver.recv().await.is_none());
    }

    #[tokio::test]
    async fn close_flushes_queued_frames_first() {
        let (conn, mut raw) = pair(100);
        conn.sender.send(b"bye".to_vec()).unwrap();
        conn.sender.close();
        let mut got = Vec::new();
        raw.read_to_end(&mut got).await.unwrap();
        assert_eq!(got, [&3u32.to_be_bytes()[..], b"bye"].concat());
    }
}
