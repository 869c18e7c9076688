//! Join tickets: which transport a master speaks, where, with which token, and
//! which certificate it presents.
//!
//! A ticket packs everything a slave or viewer needs in one string:
//!
//! | transport | ticket |
//! | --- | --- |
//! | TLS over TCP (default) | `isin://TOKEN@HOST:PORT?fp=HEX` (`isin+tcp://` also read) |
//! | QUIC | `isin+quic://TOKEN@HOST:PORT?fp=HEX` |
//! | plaintext TCP (`--insecure`) | `isin+tcp-insecure://TOKEN@HOST:PORT` |
//!
//! `fp` is the [`Fingerprint`] (SHA-256) of the master's TLS certificate,
//! which peers pin. The encrypted transports cannot be named without it, and
//! plaintext has a scheme of its own: a ticket missing its fingerprint is
//! refused, never read as plaintext, so a slave cannot be talked out of
//! encryption by trimming a ticket.
//!
//! The transport is a closed set, [`TransportKind`]: callers pick an
//! implementation with a `match`, never by comparing names. What the token
//! proves (the HMAC challenge–response) is the cluster's business, not the
//! transport's; the ticket only carries it.

use std::fmt;
use std::str::FromStr;

/// Why a ticket, transport name or fingerprint cannot be read.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum TicketError {
    /// The ticket does not have the `isin://TOKEN@ADDR` shape.
    #[error("malformed join ticket `{0}`: expected isin://TOKEN@HOST:PORT?fp=SHA256-HEX")]
    BadTicket(String),
    /// A transport name that is none of [`TransportKind::ALL`].
    #[error("unknown transport `{0}` (available: tcp, quic, tcp-insecure)")]
    UnknownTransport(String),
    /// An encrypted transport's ticket without the certificate fingerprint.
    #[error(
        "join ticket for {0} has no certificate fingerprint (`?fp=…`): pass the whole ticket the \
         master printed (a plaintext master's ticket starts with isin+tcp-insecure://)"
    )]
    MissingFingerprint(TransportKind),
    /// A plaintext ticket that names a fingerprint: one of the two is a mistake.
    #[error("a plaintext (isin+tcp-insecure://) ticket cannot carry a certificate fingerprint")]
    InsecureWithFingerprint,
    /// A fingerprint string is not 64 hex digits.
    #[error("malformed certificate fingerprint `{0}`: expected 64 hex digits (SHA-256)")]
    BadFingerprint(String),
    /// The address's port is not a port (1–65535): no retry could reach it.
    #[error("join ticket names port `{0}`: a port is a number from 1 to 65535")]
    BadPort(String),
}

/// The transports a master can speak, as named in tickets and on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TransportKind {
    /// TLS 1.3 over TCP, pinning the master's certificate (`tcp`).
    Tcp,
    /// QUIC (TLS 1.3 inside), pinning the master's certificate (`quic`).
    Quic,
    /// Plaintext TCP (`tcp-insecure`): the token still keeps strangers out,
    /// but anyone on the path can read and alter frames.
    TcpInsecure,
}

impl TransportKind {
    /// Every kind, in the order help texts list them.
    pub const ALL: [TransportKind; 3] = [TransportKind::Tcp, TransportKind::Quic, TransportKind::TcpInsecure];

    /// The name in tickets and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            TransportKind::Tcp => "tcp",
            TransportKind::Quic => "quic",
            TransportKind::TcpInsecure => "tcp-insecure",
        }
    }

    /// Whether frames are encrypted (and the ticket must carry a fingerprint).
    pub fn is_encrypted(self) -> bool {
        !matches!(self, TransportKind::TcpInsecure)
    }

    /// The ticket scheme, `isin://` for the default (TLS over TCP).
    fn scheme(self) -> &'static str {
        match self {
            TransportKind::Tcp => "isin",
            TransportKind::Quic => "isin+quic",
            TransportKind::TcpInsecure => "isin+tcp-insecure",
        }
    }
}

impl fmt::Display for TransportKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for TransportKind {
    type Err = TicketError;

    /// `tcp`, `quic` or `tcp-insecure`.
    fn from_str(s: &str) -> Result<Self, TicketError> {
        TransportKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| TicketError::UnknownTransport(s.chars().take(40).collect()))
    }
}

/// SHA-256 of a certificate's DER encoding: names the one certificate a peer
/// trusts. Parsed once from hex ([`FromStr`]); [`Display`](fmt::Display)s as
/// 64 lower-case hex digits, the form tickets carry. The hashing itself is
/// the TLS layer's (`isin_transport_tls::fingerprint_of`).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Fingerprint(pub [u8; 32]);

impl Fingerprint {
    /// The 32 bytes.
    pub fn as_bytes(&self) -> &[u8; 32] {
        &self.0
    }

    /// Constant-time comparison (the fingerprint is not secret, but this costs
    /// nothing).
    pub fn matches(&self, other: &Fingerprint) -> bool {
        self.0.iter().zip(&other.0).fold(0u8, |acc, (a, b)| acc | (a ^ b)) == 0
    }
}

impl fmt::Display for Fingerprint {
    /// Lower-case hex, 64 digits.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for b in self.0 {
            write!(f, "{b:02x}")?;
        }
        Ok(())
    }
}

impl fmt::Debug for Fingerprint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Fingerprint({self})")
    }
}

impl FromStr for Fingerprint {
    type Err = TicketError;

    /// Parses 64 hex digits (either case; `:` separators allowed, as tools print them).
    fn from_str(s: &str) -> Result<Self, TicketError> {
        let bad = || TicketError::BadFingerprint(s.chars().take(100).collect());
        let digits: Vec<u8> = s.bytes().filter(|&b| b != b':').collect();
        if digits.len() != 64 || !digits.iter().all(u8::is_ascii_hexdigit) {
            return Err(bad());
        }
        let mut out = [0u8; 32];
        for (o, pair) in out.iter_mut().zip(digits.chunks_exact(2)) {
            let hex = std::str::from_utf8(pair).map_err(|_| bad())?;
            *o = u8::from_str_radix(hex, 16).map_err(|_| bad())?;
        }
        Ok(Self(out))
    }
}

/// Everything a slave or viewer needs to join a master (see the [module
/// docs](self) for the text form).
#[derive(Clone, PartialEq, Eq)]
pub struct Ticket {
    /// Which transport the master speaks.
    pub transport: TransportKind,
    /// The shared secret.
    pub token: String,
    /// The master's address, `HOST:PORT`.
    pub addr: String,
    /// The master's certificate: peers accept it and no other. `None` for
    /// plaintext only.
    pub fingerprint: Option<Fingerprint>,
}

impl Ticket {
    /// The fingerprint to pin; [`TicketError::MissingFingerprint`] if this
    /// (hand-built) ticket has none.
    pub fn pinned(&self) -> Result<Fingerprint, TicketError> {
        self.fingerprint.ok_or(TicketError::MissingFingerprint(self.transport))
    }
}

impl fmt::Debug for Ticket {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never log the token.
        write!(f, "Ticket({} {} token=…", self.transport, self.addr)?;
        if let Some(fp) = &self.fingerprint {
            let text = fp.to_string();
            write!(f, " fp={}…", &text[..16])?;
        }
        write!(f, ")")
    }
}

impl fmt::Display for Ticket {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}://{}@{}", self.transport.scheme(), self.token, self.addr)?;
        if let Some(fp) = &self.fingerprint {
            write!(f, "?fp={fp}")?;
        }
        Ok(())
    }
}

impl FromStr for Ticket {
    type Err = TicketError;

    fn from_str(s: &str) -> Result<Self, TicketError> {
        let bad = || TicketError::BadTicket(s.chars().take(80).collect());
        let (scheme, rest) = s.split_once("://").ok_or_else(bad)?;
        let transport = match scheme {
            "isin" | "isin+tcp" => TransportKind::Tcp,
            other => other.strip_prefix("isin+").ok_or_else(bad)?.parse().map_err(|_| bad())?,
        };
        let (rest, query) = rest.split_once('?').unwrap_or((rest, ""));
        let (token, addr) = rest.rsplit_once('@').ok_or_else(bad)?;
        if token.is_empty() || addr.is_empty() || !addr.contains(':') {
            return Err(bad());
        }
        let port = addr.rsplit_once(':').map_or("", |(_, p)| p);
        if !port.parse::<u16>().is_ok_and(|p| p > 0) {
            return Err(TicketError::BadPort(port.chars().take(20).collect()));
        }
        let mut fingerprint = None;
        // Unknown parameters are left to newer builds; a fingerprint must be well-formed.
        for (key, value) in query.split('&').filter(|p| !p.is_empty()).filter_map(|p| p.split_once('=')) {
            if key == "fp" {
                // Tickets carry bare hex (no `:`), exactly 64 digits.
                if value.contains(':') {
                    return Err(bad());
                }
                fingerprint = Some(value.parse::<Fingerprint>().map_err(|_| bad())?);
            }
        }
        match (transport.is_encrypted(), &fingerprint) {
            (true, None) => return Err(TicketError::MissingFingerprint(transport)),
            (false, Some(_)) => return Err(TicketError::InsecureWithFingerprint),
            _ => {}
        }
        Ok(Ticket { transport, token: token.to_string(), addr: addr.to_string(), fingerprint })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fp(hex: &str) -> Fingerprint {
        hex.parse().unwrap()
    }

    #[test]
    fn transport_kinds_round_trip_their_names() {
        for k in TransportKind::ALL {
            assert_eq!(k.name().parse::<TransportKind>().unwrap(), k);
            assert_eq!(k.to_string(), k.name());
        }
        assert!(matches!("udp".parse::<TransportKind>(), Err(TicketError::UnknownTransport(_))));
        assert!(!TransportKind::TcpInsecure.is_encrypted());
        assert!(TransportKind::Tcp.is_encrypted() && TransportKind::Quic.is_encrypted());
    }

    #[test]
    fn fingerprints_print_and_parse() {
        let text = "0123456789abcdef".repeat(4);
        let f = fp(&text);
        assert_eq!(f.to_string(), text);
        assert_eq!(f.as_bytes()[..2], [0x01, 0x23]);
        assert_eq!(fp(&text.to_uppercase()), f);
        let colons: String =
            text.as_bytes().chunks(2).map(|c| std::str::from_utf8(c).unwrap()).collect::<Vec<_>>().join(":");
        assert_eq!(fp(&colons), f);
        assert!(f.matches(&f) && !f.matches(&Fingerprint([0; 32])));
        for bad in [
            "",
            "abc",
            &text[..62],
            &format!("{}zz", &text[..62]),
            &format!("{text}00"),
            "+1".repeat(32).as_str(),
        ] {
            assert!(matches!(bad.parse::<Fingerprint>(), Err(TicketError::BadFingerprint(_))), "{bad}");
        }
    }

    #[test]
    fn a_port_that_cannot_exist_is_refused_at_once() {
        for port in ["99999", "0", "http", ""] {
            let t = format!("isin+tcp-insecure://tok@host:{port}").parse::<Ticket>();
            assert!(matches!(t, Err(TicketError::BadPort(_))), "{port}: {t:?}");
        }
        assert!("isin+tcp-insecure://tok@host:65535".parse::<Ticket>().is_ok());
    }

    #[test]
    fn tickets_round_trip() {
        let hex = "ab".repeat(32);
        for text in [
            format!("isin://abc@127.0.0.1:7878?fp={hex}"),
            format!("isin+quic://t0k@[::1]:9000?fp={hex}"),
            "isin+tcp-insecure://t0k@host:1".to_string(),
        ] {
            let t: Ticket = text.parse().unwrap();
            assert_eq!(t.to_string(), text);
        }
        let t: Ticket = format!("isin+tcp://abc@127.0.0.1:7878?fp={hex}").parse().unwrap();
        assert_eq!(
            (t.transport, t.token.as_str(), t.addr.as_str()),
            (TransportKind::Tcp, "abc", "127.0.0.1:7878")
        );
        assert_eq!(t.pinned(), Ok(fp(&hex)));
        assert!(!format!("{t:?}").contains("abc"));
        assert_eq!(t.to_string(), format!("isin://abc@127.0.0.1:7878?fp={hex}"));
        let plain: Ticket = "isin+tcp-insecure://abc@h:1".parse().unwrap();
        assert_eq!((plain.transport, plain.fingerprint), (TransportKind::TcpInsecure, None));
        assert_eq!(plain.pinned(), Err(TicketError::MissingFingerprint(TransportKind::TcpInsecure)));
    }

    #[test]
    fn encrypted_tickets_without_a_fingerprint_are_never_read_as_plaintext() {
        for text in ["isin://abc@127.0.0.1:7878", "isin+tcp://abc@h:1", "isin+quic://abc@h:1"] {
            let err = text.parse::<Ticket>().unwrap_err();
            assert!(matches!(err, TicketError::MissingFingerprint(_)), "{text}: {err:?}");
            assert!(err.to_string().contains("isin+tcp-insecure://"), "{err}");
        }
        let hex = "cd".repeat(32);
        let err = format!("isin+tcp-insecure://abc@h:1?fp={hex}").parse::<Ticket>().unwrap_err();
        assert_eq!(err, TicketError::InsecureWithFingerprint);
    }

    #[test]
    fn tickets_carry_the_certificate_fingerprint() {
        let hex = "0123456789abcdef".repeat(4);
        let text = format!("isin+quic://tok@10.0.0.1:7878?fp={hex}");
        let t: Ticket = text.parse().unwrap();
        assert_eq!((t.addr.as_str(), t.fingerprint), ("10.0.0.1:7878", Some(fp(&hex))));
        assert_eq!(t.to_string(), text);
        let upper: Ticket = format!("isin://tok@h:1?fp={}", hex.to_uppercase()).parse().unwrap();
        assert_eq!(upper.transport, TransportKind::Tcp);
        assert_eq!(upper.fingerprint, Some(fp(&hex)));
        assert_eq!(upper.to_string(), format!("isin://tok@h:1?fp={hex}"), "printed in lower case");
        assert!(!format!("{t:?}").contains("tok@"));
        for bad in [
            format!("isin+quic://tok@h:1?fp={}", &hex[..63]),
            format!("isin+quic://tok@h:1?fp={}g", &hex[..63]),
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
            "isin+udp://a@b:1",
        ] {
            assert!(text.parse::<Ticket>().is_err(), "{text}");
        }
    }
}
