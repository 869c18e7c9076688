//! Authentication: proving knowledge of the shared token.
//!
//! The master and every peer share a secret token, which never crosses the
//! wire. On connect the master sends a fresh 32-byte nonce; the peer answers
//! with its own nonce and `HMAC-SHA256(token, "isin-client" ‖ version ‖ role ‖
//! server nonce ‖ client nonce)`; the master checks it in constant time and, if
//! it holds, proves its own knowledge of the token with the same HMAC under the
//! label `"isin-server"`. Neither proof can be replayed: each covers a nonce
//! chosen by the other side.
//!
//! Join tickets (the token, the master's address, transport and certificate
//! fingerprint in one string) are the transports' business and live in
//! `isin_transport::ticket`; this module only proves knowledge of the token.

use crate::protocol::{PROTOCOL_VERSION, Role};
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::fmt;

type HmacSha256 = Hmac<Sha256>;

/// Why authentication material could not be made.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AuthError {
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

/// A secret for one purpose, `label`, derived from `key` (HMAC-SHA256):
/// one seed keys several things without one revealing another.
pub fn derive(key: &[u8; 32], label: &[u8]) -> [u8; 32] {
    let mut m = HmacSha256::new_from_slice(key).expect("HMAC accepts keys of any length");
    m.update(label);
    m.finalize().into_bytes().into()
}

/// Constant-time comparison of two proofs.
pub fn proofs_match(a: &[u8; 32], b: &[u8; 32]) -> bool {
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
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
}
