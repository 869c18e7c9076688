//! Authentication and join tickets.
//!
//! The master and every peer share a secret token, which never crosses the
//! wire. On connect the master sends a fresh 32-byte nonce; the peer answers
//! with its own nonce and `HMAC-SHA256(token, "isin-client" ‖ version ‖ role ‖
//! server nonce ‖ client nonce)`; the master checks it in constant time and, if
//! it holds, proves its own knowledge of the token with the same HMAC under the
//! label `"isin-server"`. Neither proof can be replayed: each covers a nonce
//! chosen by the other side.
//!
//! A join ticket packs the transport, token and address in one string:
//!
//! | transport | ticket |
//! | --- | --- |
//! | TLS over TCP (default) | `isin://TOKEN@HOST:PORT?fp=HEX` (`isin+tcp://` also read) |
//! | QUIC | `isin+quic://TOKEN@HOST:PORT?fp=HEX` |
//! | plaintext TCP (`--insecure`) | `isin+tcp-insecure://TOKEN@HOST:PORT` |
//!
//! `fp` is the SHA-256 of the master's TLS certificate, which peers pin. The
//! encrypted transports cannot be named without it, and plaintext has a
//! scheme of its own: a ticket missing its fingerprint is refused, never read
//! as plaintext, so a slave cannot be talked out of encryption by trimming a
//! ticket.

use crate::protocol::{PROTOCOL_VERSION, Role};
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::fmt;

type HmacSha256 = Hmac<Sha256>;

/// Why a ticket or token is not usable.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AuthError {
    /// The ticket does not have the `isin://TOKEN@ADDR` shape.
    #[error("malformed join ticket `{0}`: expected isin://TOKEN@HOST:PORT?fp=SHA256-HEX")]
    BadTicket(String),
    /// An encrypted transport's ticket without the certificate fingerprint.
    #[error(
        "join ticket for {0} has no certificate fingerprint (`?fp=…`): pass the whole ticket the \
         master printed (a plaintext master's ticket starts with isin+tcp-insecure://)"
    )]
    MissingFingerprint(String),
    /// A plaintext ticket that names a fingerprint: one of the two is a mistake.
    #[error("a plaintext (isin+tcp-insecure://) ticket cannot carry a certificate fingerprint")]
    InsecureWithFingerprint,
    /// The operating system's random source failed.
    #[error("no randomness available: {0}")]
    Random(String),
}

/// `n` bytes from the operating system's random source.
pub fn random_bytes<const N: usize>() -> Result<[u8; N], AuthError> {
    let mut out = [0u8; N];
    getrandom::fill(&mut out).map_err(|e| AuthError::Random(e.to_string()))?;
    Ok(out)
}

/// A fresh random token: 32 hex digits (128 bits).
pub fn generate_token() -> Result<String, AuthError> {
    let bytes: [u8; 16] = random_bytes()?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// Fresh challenge nonces without asking the operating system each time:
/// `HMAC-SHA256(seed, counter)`, unpredictable to anyone who does not know the
/// seed and never repeated. The master's core takes its seed from
/// [`random_bytes`] at start (tests give a fixed one, so runs repeat).
#[derive(Clone)]
pub struct Nonces {
    seed: [u8; 32],
    counter: u64,
}

impl Nonces {
    /// A source keyed by `seed` (32 random bytes).
    pub fn new(seed: [u8; 32]) -> Self {
        Self { seed, counter: 0 }
    }

    /// The next nonce.
    pub fn next_nonce(&mut self) -> [u8; 32] {
        self.counter += 1;
        let mut m = HmacSha256::new_from_slice(&self.seed).expect("HMAC accepts keys of any length");
        m.update(b"isin-nonce");
        m.update(&self.counter.to_be_bytes());
        m.finalize().into_bytes().into()
    }
}

impl fmt::Debug for Nonces {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never log the seed.
        write!(f, "Nonces(#{})", self.counter)
    }
}

fn mac(token: &str, label: &[u8], role: Role, server_nonce: &[u8; 32], client_nonce: &[u8; 32]) -> [u8; 32] {
    let mut m = HmacSha256::new_from_slice(token.as_bytes()).expect("HMAC accepts keys of any length");
    m.update(label);
    m.update(&PROTOCOL_VERSION.to_be_bytes());
    m.update(&[match role {
        Role::Slave => 1,
        Role::Viewer => 2,
    }]);
    m.update(server_nonce);
    m.update(client_nonce);
    m.finalize().into_bytes().into()
}

/// The peer's proof of the token for this handshake.
pub fn client_proof(token: &str, role: Role, server_nonce: &[u8; 32], client_nonce: &[u8; 32]) -> [u8; 32] {
    mac(token, b"isin-client", role, server_nonce, client_nonce)
}

/// The master's proof of the token for this handshake.
pub fn server_proof(token: &str, role: Role, server_nonce: &[u8; 32], client_nonce: &[u8; 32]) -> [u8; 32] {
    mac(token, b"isin-server", role, server_nonce, client_nonce)
}

/// Constant-time comparison of two proofs.
pub fn proofs_match(a: &[u8; 32], b: &[u8; 32]) -> bool {
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Transport name of TLS over TCP.
pub const ENCRYPTED_TCP: &str = "tcp";
/// Transport name of plaintext TCP.
pub const PLAINTEXT_TCP: &str = "tcp-insecure";

/// Everything a slave or viewer needs to join a master.
#[derive(Clone, PartialEq, Eq)]
pub struct Ticket {
    /// Transport name: `tcp` (TLS), `quic`, or `tcp-insecure` (plaintext).
    pub transport: String,
    /// The shared secret.
    pub token: String,
    /// The master's address, `HOST:PORT`.
    pub addr: String,
    /// SHA-256 of the master's TLS certificate, 64 lower-case hex digits:
    /// peers accept that certificate and no other. `None` for plaintext.
    pub fingerprint: Option<String>,
}

impl fmt::Debug for Ticket {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never log the token.
        write!(f, "Ticket({} {} token=…", self.transport, self.addr)?;
        if let Some(fp) = &self.fingerprint {
            write!(f, " fp={}…", fp.get(..16).unwrap_or(fp))?;
        }
        write!(f, ")")
    }
}

impl fmt::Display for Ticket {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.transport == "tcp" {
            write!(f, "isin://{}@{}", self.token, self.addr)?;
        } else {
            write!(f, "isin+{}://{}@{}", self.transport, self.token, self.addr)?;
        }
        if let Some(fp) = &self.fingerprint {
            write!(f, "?fp={fp}")?;
        }
        Ok(())
    }
}

impl std::str::FromStr for Ticket {
    type Err = AuthError;

    fn from_str(s: &str) -> Result<Self, AuthError> {
        let bad = || AuthError::BadTicket(s.chars().take(80).collect());
        let (scheme, rest) = s.split_once("://").ok_or_else(bad)?;
        let transport = match scheme {
            "isin" | "isin+tcp" => "tcp".to_string(),
            other => other.strip_prefix("isin+").filter(|t| !t.is_empty()).ok_or_else(bad)?.to_string(),
        };
        let (rest, query) = rest.split_once('?').unwrap_or((rest, ""));
        let (token, addr) = rest.rsplit_once('@').ok_or_else(bad)?;
        if token.is_empty() || addr.is_empty() || !addr.contains(':') {
            return Err(bad());
        }
        let mut fingerprint = None;
        // Unknown parameters are left to newer builds; a fingerprint must be well-formed.
        for (key, value) in query.split('&').filter(|p| !p.is_empty()).filter_map(|p| p.split_once('=')) {
            if key == "fp" {
                if value.len() != 64 || !value.bytes().all(|b| b.is_ascii_hexdigit()) {
                    return Err(bad());
                }
                fingerprint = Some(value.to_ascii_lowercase());
            }
        }
        match (transport.as_str(), &fingerprint) {
            (ENCRYPTED_TCP | "quic", None) => return Err(AuthError::MissingFingerprint(transport)),
            (PLAINTEXT_TCP, Some(_)) => return Err(AuthError::InsecureWithFingerprint),
            _ => {}
        }
        Ok(Ticket { transport, token: token.to_string(), addr: addr.to_string(), fingerprint })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn proofs_depend_on_token_nonces_role_and_direction() {
        let (s, c) = ([1u8; 32], [2u8; 32]);
        let p = client_proof("secret", Role::Slave, &s, &c);
        assert!(proofs_match(&p, &client_proof("secret", Role::Slave, &s, &c)));
        assert!(!proofs_match(&p, &client_proof("secret!", Role::Slave, &s, &c)));
        assert!(!proofs_match(&p, &client_proof("secret", Role::Viewer, &s, &c)));
        assert!(!proofs_match(&p, &client_proof("secret", Role::Slave, &c, &s)));
        assert!(!proofs_match(&p, &server_proof("secret", Role::Slave, &s, &c)));
    }

    #[test]
    fn nonces_never_repeat_and_depend_on_the_seed() {
        let mut a = Nonces::new([1; 32]);
        let mut b = Nonces::new([2; 32]);
        let (a1, a2, b1) = (a.next_nonce(), a.next_nonce(), b.next_nonce());
        assert_ne!(a1, a2);
        assert_ne!(a1, b1);
        assert_eq!(Nonces::new([1; 32]).next_nonce(), a1);
    }

    #[test]
    fn tokens_are_random_hex() {
        let a = generate_token().unwrap();
        let b = generate_token().unwrap();
        assert_eq!(a.len(), 32);
        assert!(a.chars().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, b);
    }

    #[test]
    fn tickets_round_trip() {
        let fp = "ab".repeat(32);
        for text in [
            format!("isin://abc@127.0.0.1:7878?fp={fp}"),
            format!("isin+quic://t0k@[::1]:9000?fp={fp}"),
            "isin+tcp-insecure://t0k@host:1".to_string(),
        ] {
            let t: Ticket = text.parse().unwrap();
            assert_eq!(t.to_string(), text);
        }
        let t: Ticket = format!("isin+tcp://abc@127.0.0.1:7878?fp={fp}").parse().unwrap();
        assert_eq!(
            (t.transport.as_str(), t.token.as_str(), t.addr.as_str()),
            ("tcp", "abc", "127.0.0.1:7878")
        );
        assert!(!format!("{t:?}").contains("abc"));
        assert_eq!(t.to_string(), format!("isin://abc@127.0.0.1:7878?fp={fp}"));
        let plain: Ticket = "isin+tcp-insecure://abc@h:1".parse().unwrap();
        assert_eq!((plain.transport.as_str(), plain.fingerprint), ("tcp-insecure", None));
    }

    #[test]
    fn encrypted_tickets_without_a_fingerprint_are_never_read_as_plaintext() {
        for text in ["isin://abc@127.0.0.1:7878", "isin+tcp://abc@h:1", "isin+quic://abc@h:1"] {
            let err = text.parse::<Ticket>().unwrap_err();
            assert!(matches!(err, AuthError::MissingFingerprint(_)), "{text}: {err:?}");
            assert!(err.to_string().contains("isin+tcp-insecure://"), "{err}");
        }
        let fp = "cd".repeat(32);
        let err = format!("isin+tcp-insecure://abc@h:1?fp={fp}").parse::<Ticket>().unwrap_err();
        assert_eq!(err, AuthError::InsecureWithFingerprint);
    }

    #[test]
    fn tickets_carry_the_certificate_fingerprint() {
        let fp = "0123456789abcdef".repeat(4);
        let text = format!("isin+quic://tok@10.0.0.1:7878?fp={fp}");
        let t: Ticket = text.parse().unwrap();
        assert_eq!((t.addr.as_str(), t.fingerprint.as_deref()), ("10.0.0.1:7878", Some(fp.as_str())));
        assert_eq!(t.to_string(), text);
        let upper: Ticket = format!("isin://tok@h:1?fp={}", fp.to_uppercase()).parse().unwrap();
        assert_eq!(upper.transport, "tcp");
        assert_eq!(upper.fingerprint.as_deref(), Some(fp.as_str()));
        assert!(!format!("{t:?}").contains("tok@"));
        for bad in [
            format!("isin+quic://tok@h:1?fp={}", &fp[..63]),
            format!("isin+quic://tok@h:1?fp={}g", &fp[..63]),
        ] {
            assert!(bad.parse::<Ticket>().is_err(), "{bad}");
        }
    }

    #[test]
    fn malformed_tickets_are_refused() {
        for text in [
            "",
            "127.0.0.1:7878",
            "http://a@b:1",
            "isin+tcp-insecure://@h:1",
            "isin+tcp-insecure://tok@",
            "isin+tcp-insecure://tok@host",
            "isin+://a@b:1",
        ] {
            assert!(text.parse::<Ticket>().is_err(), "{text}");
        }
    }
}
