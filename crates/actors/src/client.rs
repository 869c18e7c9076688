//! The peer side of the handshake, shared by slaves and viewers: connect,
//! answer the master's challenge, check the master's own proof.

use isin_cluster::auth;
use isin_cluster::codec::Codec;
use isin_cluster::protocol::{
    self, DEFAULT_MAX_FRAME, DirectOffer, HANDSHAKE_MAX_FRAME, Hello, Message, Role, SceneHash, Welcome,
};
use isin_cluster::scheduler::Work;
use isin_transport::{Connection, Ticket, Transport, TransportError};
use std::time::Duration;

/// How long one frame from the master may take to arrive once begun: a
/// frame of [`isin_cluster::protocol::DEFAULT_MAX_FRAME`] over 10 Mbit/s, with
/// room to spare (scenes come in 256 KiB chunks, far below it).
pub const SCENE_FRAME_TIMEOUT: Duration = Duration::from_secs(600);

/// How long each handshake step may take.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Why joining a master failed.
#[derive(Debug, thiserror::Error)]
pub enum JoinError {
    /// The network failed (worth retrying).
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The master refused us (not worth retrying: e.g. wrong token).
    #[error("master refused: {0}")]
    Rejected(String),
    /// The master could not prove it knows the token.
    #[error("master failed to prove it knows the token: not the master of this ticket")]
    MasterUnauthenticated,
    /// The master spoke nonsense or another protocol version.
    #[error("protocol error: {0}")]
    Protocol(#[from] protocol::ProtocolError),
    /// The master sent a message we did not expect here.
    #[error("unexpected {0} message from the master")]
    Unexpected(&'static str),
    /// The master did not answer in time.
    #[error("master did not answer within {0:?}")]
    Timeout(Duration),
    /// The master closed the connection.
    #[error("master closed the connection")]
    Closed,
    /// The scene the master sent could not be loaded.
    #[error("cannot load the master's scene: {0}")]
    Scene(String),
}

impl JoinError {
    /// Whether trying again later could help.
    pub fn is_retryable(&self) -> bool {
        match self {
            JoinError::Transport(TransportError::Untrusted { .. }) => false,
            JoinError::Transport(_) | JoinError::Timeout(_) | JoinError::Closed => true,
            _ => false,
        }
    }
}

/// Receives and decodes the next message, with a timeout.
pub async fn recv_message(
    conn: &mut Connection,
    max: usize,
    timeout: Duration,
) -> Result<Message, JoinError> {
    match tokio::time::timeout(timeout, conn.receiver.recv()).await {
        Err(_) => Err(JoinError::Timeout(timeout)),
        Ok(None) => Err(JoinError::Closed),
        Ok(Some(Err(e))) => Err(e.into()),
        Ok(Some(Ok(frame))) => Ok(protocol::decode(&frame, max)?),
    }
}

/// Encodes and sends a message.
pub fn send_message(conn: &Connection, msg: &Message) -> Result<(), JoinError> {
    conn.sender.send(protocol::encode(msg)?)?;
    Ok(())
}

/// Who joins a master, and as what.
#[derive(Clone, Copy, Debug)]
pub struct Join<'a> {
    /// Slave or viewer.
    pub role: Role,
    /// Name for the master's logs.
    pub name: &'a str,
    /// Render threads (slaves).
    pub threads: u32,
    /// The scenes held already (slaves): they are not sent again.
    pub cached_scenes: &'a [SceneHash],
    /// Tile codecs offered (the master's choice is in the [`Welcome`]).
    pub codecs: &'a [Codec],
    /// What kind of work the frames are (viewers).
    pub work: Work,
    /// Where slaves may send the viewer's tiles straight (viewers).
    pub direct: Option<&'a DirectOffer>,
}

impl<'a> Join<'a> {
    /// A slave with `threads` render threads.
    pub fn slave(name: &'a str, threads: u32, cached_scenes: &'a [SceneHash], codecs: &'a [Codec]) -> Self {
        Self {
            role: Role::Slave,
            name,
            threads,
            cached_scenes,
            codecs,
            work: Work::Interactive,
            direct: None,
        }
    }

    /// A viewer whose frames are `work`, decoding every codec.
    pub fn viewer(name: &'a str, work: Work) -> Self {
        Self {
            role: Role::Viewer,
            name,
            threads: 0,
            cached_scenes: &[],
            codecs: &Codec::ALL,
            work,
            direct: None,
        }
    }
}

/// Connects to the master of `ticket` and authenticates as `join` says.
pub async fn handshake(
    transport: &dyn Transport,
    ticket: &Ticket,
    join: Join<'_>,
) -> Result<(Connection, Welcome), JoinError> {
    let Join { role, name, threads, cached_scenes, codecs, work, direct } = join;
    let mut conn = tokio::time::timeout(HANDSHAKE_TIMEOUT, transport.connect(&ticket.addr))
        .await
        .map_err(|_| JoinError::Timeout(HANDSHAKE_TIMEOUT))??;
    let nonce = match recv_message(&mut conn, HANDSHAKE_MAX_FRAME, HANDSHAKE_TIMEOUT).await? {
        Message::Challenge { nonce } => nonce,
        Message::Reject { reason } => return Err(JoinError::Rejected(reason)),
        other => return Err(JoinError::Unexpected(other.kind())),
    };
    let client_nonce = auth::random_bytes::<32>().map_err(|e| JoinError::Scene(e.to_string()))?;
    let proof = auth::client_proof(&ticket.token, role, &nonce, &client_nonce);
    let codecs = codecs.iter().map(|c| c.name().to_string()).collect();
    let cached_scenes = cached_scenes.iter().take(protocol::MAX_CACHED_SCENES).copied().collect();
    let direct = direct.cloned().map(Box::new);
    let name = name.to_string();
    let hello = Hello { role, name, threads, client_nonce, proof, cached_scenes, codecs, work, direct };
    send_message(&conn, &Message::Hello(hello))?;
    // The master's welcome is small, but what follows (the scene) is not,
    // and may take minutes on a slow link.
    conn.sender.set_max_frame(DEFAULT_MAX_FRAME);
    conn.sender.set_frame_timeout(SCENE_FRAME_TIMEOUT);
    let welcome = match recv_message(&mut conn, DEFAULT_MAX_FRAME, HANDSHAKE_TIMEOUT).await? {
        Message::Welcome(w) => w,
        Message::Reject { reason } => return Err(JoinError::Rejected(reason)),
        other => return Err(JoinError::Unexpected(other.kind())),
    };
    let expected = auth::server_proof(&ticket.token, role, &nonce, &client_nonce);
    if !auth::proofs_match(&expected, &welcome.proof) {
        conn.sender.close();
        return Err(JoinError::MasterUnauthenticated);
    }
    Ok((conn, welcome))
}
