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
//! `isin://TOKEN@HOST:PORT` for TCP, `isin+quic://TOKEN@HOST:PORT` for QUIC,
//! followed by `?fp=HEX` — the SHA-256 of the master's TLS certificate, which
//! peers pin — when the transport is encrypted.

use crate::protocol::{PROTOCOL_VERSION, Role};
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::fmt;

type HmacSha256 = Hmac<Sha256>;

/// Why a ticket or token is not usable.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AuthError {
    /// The ticket does not have the `isin://TOKEN@ADDR` shape.
    #[error("malformed join ticket `{0}`: expected isin://TOKEN@HOST:PORT[?fp=SHA256-HEX]")]
    BadTicket(String),
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

/// Everything a slave or viewer needs to join a master.
#[derive(Clone, PartialEq, Eq)]
pub struct Ticket {
    /// Transport name: `tcp` or `quic`.
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
            "isin" => "tcp".to_string(),
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
    fn tokens_are_random_hex() {
        let a = generate_token().unwrap();
        let b = generate_token().unwrap();
        assert_eq!(a.len(), 32);
        assert!(a.chars().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, b);
    }

    #[test]
    fn tickets_round_trip() {
        for text in ["isin://abc@127.0.0.1:7878", "isin+quic://t0k@[::1]:9000"] {
            let t: Ticket = text.parse().unwrap();
            assert_eq!(t.to_string(), text);
        }
        let t: Ticket = "isin://abc@127.0.0.1:7878".parse().unwrap();
        assert_eq!(
            (t.transport.as_str(), t.token.as_str(), t.addr.as_str()),
            ("tcp", "abc", "127.0.0.1:7878")
        );
        assert!(!format!("{t:?}").contains("abc"));
        assert_eq!(t.fingerprint, None);
    }

    #[test]
    fn tickets_carry_the_certificate_fingerprint() {
        let fp = "0123456789abcdef".repeat(4);
        let text = format!("isin+quic://tok@10.0.0.1:7878?fp={fp}");
        let t: Ticket = text.parse().unwrap();
        assert_eq!((t.addr.as_str(), t.fingerprint.as_deref()), ("10.0.0.1:7878", Some(fp.as_str())));
        assert_eq!(t.to_string(), text);
        let upper: Ticket = format!("isin://tok@h:1?fp={}", fp.to_uppercase()).parse().unwrap();
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
            "isin://@h:1",
            "isin://tok@",
            "isin://tok@host",
            "isin+://a@b:1",
        ] {
            assert!(text.parse::<Ticket>().is_err(), "{text}");
        }
    }
}
