//! # isin-transport-tls — the master's TLS identity and certificate pinning
//!
//! One TLS layer under both encrypted transports: TLS over TCP
//! (`isin-transport-tcp`, through `tokio-rustls`) and QUIC
//! (`isin-transport-quic`, through quinn). It lives in a crate of its own so
//! that neither transport depends on the other, and the actors and the
//! cluster core stay free of cryptography.
//!
//! The master generates a self-signed certificate ([`Identity::generate`]); the
//! SHA-256 of its DER encoding, the [`Fingerprint`] ([`fingerprint_of`]),
//! travels in the join ticket (`isin_transport::ticket`). A peer trusts
//! exactly that certificate: [`PinnedServerVerifier`] accepts the handshake
//! only if the server's end-entity certificate hashes to the pinned
//! fingerprint, and checks the handshake signatures with the ring provider's
//! algorithms, so the server must also hold the certificate's private key.
//! There is no certificate authority and no "accept anything" mode; the server
//! name is not checked (the fingerprint names the server more precisely than
//! any host name could).
//!
//! [`server_config`] and [`client_config`] build plain rustls configurations
//! (TLS 1.3 only, ring provider) with the ALPN protocol chosen by the caller:
//! the TCP transport wraps them in `tokio-rustls`, QUIC hands them to quinn.

pub use isin_transport::ticket::Fingerprint;
use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::{CryptoProvider, WebPkiSupportedAlgorithms};
use rustls::pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer, ServerName, UnixTime};
use rustls::{DigitallySignedStruct, SignatureScheme};
use sha2::{Digest, Sha256};
use std::fmt;
use std::sync::{Arc, Mutex};

/// ALPN protocol of isin over QUIC.
pub const ALPN_QUIC: &[u8] = b"isin-quic/1";
/// ALPN protocol of isin over TLS over TCP.
pub const ALPN_TCP: &[u8] = b"isin-tcp/1";
/// Server name the client presents (SNI); never checked, see the module docs.
pub const SERVER_NAME: &str = "isin";

/// Why a TLS configuration could not be built.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// The certificate could not be generated.
    #[error("cannot generate a certificate: {0}")]
    Generate(String),
    /// rustls refused the configuration (key does not match, …).
    #[error("invalid TLS configuration: {0}")]
    Config(#[from] rustls::Error),
    /// The configuration does not suit QUIC (e.g. no TLS 1.3 initial cipher suite).
    #[error("TLS configuration unusable for QUIC: {0}")]
    Quic(String),
}

/// The fingerprint of a DER-encoded certificate: its SHA-256.
pub fn fingerprint_of(cert_der: &[u8]) -> Fingerprint {
    Fingerprint(Sha256::digest(cert_der).into())
}

/// A certificate and its private key: what a TLS server presents.
pub struct Identity {
    cert: CertificateDer<'static>,
    key: PrivatePkcs8KeyDer<'static>,
    fingerprint: Fingerprint,
}

impl fmt::Debug for Identity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never print the key.
        write!(f, "Identity({})", self.fingerprint)
    }
}

impl Clone for Identity {
    fn clone(&self) -> Self {
        Self { cert: self.cert.clone(), key: self.key.clone_key(), fingerprint: self.fingerprint }
    }
}

impl Identity {
    /// A fresh self-signed certificate (ECDSA P-256) for the name `isin`.
    pub fn generate() -> Result<Self, TlsError> {
        let names = vec![SERVER_NAME.to_string(), "localhost".to_string()];
        let certified =
            rcgen::generate_simple_self_signed(names).map_err(|e| TlsError::Generate(e.to_string()))?;
        let key = PrivatePkcs8KeyDer::from(certified.signing_key.serialize_der());
        Ok(Self::from_der(certified.cert.der().clone(), key))
    }

    /// An identity from a DER certificate and its PKCS#8 DER private key (e.g.
    /// loaded from files so the fingerprint survives restarts). Whether the key
    /// matches the certificate is checked by [`server_config`].
    pub fn from_der(cert: CertificateDer<'static>, key: PrivatePkcs8KeyDer<'static>) -> Self {
        let fingerprint = fingerprint_of(&cert);
        Self { cert, key, fingerprint }
    }

    /// The certificate's SHA-256: what the join ticket carries.
    pub fn fingerprint(&self) -> Fingerprint {
        self.fingerprint
    }

    /// The certificate, DER-encoded.
    pub fn cert_der(&self) -> &CertificateDer<'static> {
        &self.cert
    }

    /// The private key, PKCS#8 DER-encoded.
    pub fn key_der(&self) -> &PrivatePkcs8KeyDer<'static> {
        &self.key
    }
}

/// The crypto provider every isin TLS configuration uses.
pub fn provider() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// A TLS 1.3 server configuration presenting `identity`, offering `alpn`
/// (e.g. [`ALPN_QUIC`] or [`ALPN_TCP`]). No client certificates: peers
/// authenticate with the token inside the session.
pub fn server_config(identity: &Identity, alpn: &[&[u8]]) -> Result<rustls::ServerConfig, TlsError> {
    let mut cfg = rustls::ServerConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])?
        .with_no_client_auth()
        .with_single_cert(vec![identity.cert.clone()], PrivateKeyDer::Pkcs8(identity.key.clone_key()))?;
    cfg.alpn_protocols = alpn.iter().map(|p| p.to_vec()).collect();
    // No session resumption (every peer does the full handshake and the token
    // challenge anyway): no tickets to send, and none left unread in a peer's
    // socket to turn its close into a reset.
    cfg.send_tls13_tickets = 0;
    Ok(cfg)
}

/// A TLS 1.3 client configuration that trusts only the server certificate
/// whose SHA-256 is `pinned`, offering `alpn`.
pub fn client_config(pinned: Fingerprint, alpn: &[&[u8]]) -> Result<rustls::ClientConfig, TlsError> {
    client_config_with(Arc::new(PinnedServerVerifier::new(pinned, &provider())), alpn)
}

/// [`client_config`] around a verifier the caller keeps, e.g. to ask it after
/// a failed handshake whether the fingerprint was the reason
/// ([`PinnedServerVerifier::rejected`]).
pub fn client_config_with(
    verifier: Arc<PinnedServerVerifier>,
    alpn: &[&[u8]],
) -> Result<rustls::ClientConfig, TlsError> {
    let mut cfg = rustls::ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])?
        .dangerous()
        .with_custom_certificate_verifier(verifier)
        .with_no_client_auth();
    cfg.alpn_protocols = alpn.iter().map(|p| p.to_vec()).collect();
    Ok(cfg)
}

/// The certificate a server presented did not have the pinned fingerprint.
#[derive(Clone, Debug, thiserror::Error)]
#[error(
    "server certificate fingerprint {got} does not match the ticket's {want} \
     (wrong ticket, or not the master it names)"
)]
pub struct FingerprintMismatch {
    /// The ticket's fingerprint.
    pub want: Fingerprint,
    /// The presented certificate's.
    pub got: Fingerprint,
}

/// Trusts exactly one server certificate, named by its SHA-256 (see the
/// [module docs](self)).
#[derive(Debug)]
pub struct PinnedServerVerifier {
    pinned: Fingerprint,
    algorithms: WebPkiSupportedAlgorithms,
    rejected: Mutex<Option<FingerprintMismatch>>,
}

impl PinnedServerVerifier {
    /// A verifier pinning `pinned`, checking signatures with `provider`'s algorithms.
    pub fn new(pinned: Fingerprint, provider: &CryptoProvider) -> Self {
        Self { pinned, algorithms: provider.signature_verification_algorithms, rejected: Mutex::new(None) }
    }

    /// The fingerprint this verifier trusts.
    pub fn pinned(&self) -> Fingerprint {
        self.pinned
    }

    /// The last certificate refused for its fingerprint, if any (TLS stacks
    /// report verifier errors in their own words; this is the clear one).
    pub fn rejected(&self) -> Option<FingerprintMismatch> {
        self.rejected.lock().ok().and_then(|r| r.clone())
    }
}

impl ServerCertVerifier for PinnedServerVerifier {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        _intermediates: &[CertificateDer<'_>],
        _server_name: &ServerName<'_>,
        _ocsp_response: &[u8],
        _now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        let got = fingerprint_of(end_entity);
        if got.matches(&self.pinned) {
            Ok(ServerCertVerified::assertion())
        } else {
            tracing::warn!(%got, want = %self.pinned, "server certificate does not match the pinned fingerprint");
            let err = FingerprintMismatch { want: self.pinned, got };
            if let Ok(mut slot) = self.rejected.lock() {
                *slot = Some(err.clone());
            }
            Err(rustls::Error::InvalidCertificate(rustls::CertificateError::Other(rustls::OtherError(
                Arc::new(err),
            ))))
        }
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls12_signature(message, cert, dss, &self.algorithms)
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls13_signature(message, cert, dss, &self.algorithms)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.algorithms.supported_schemes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fingerprints_are_the_certificates_sha256_and_survive_the_ticket_form() {
        let id = Identity::generate().unwrap();
        let fp = id.fingerprint();
        assert_eq!(fingerprint_of(id.cert_der()), fp);
        let expected: [u8; 32] = Sha256::digest(id.cert_der()).into();
        assert_eq!(fp.as_bytes(), &expected);
        assert_eq!(fp.to_string().parse::<Fingerprint>().unwrap(), fp);
    }

    #[test]
    fn identities_are_fresh_and_debug_hides_the_key() {
        let a = Identity::generate().unwrap();
        let b = Identity::generate().unwrap();
        assert_ne!(a.fingerprint(), b.fingerprint());
        assert_eq!(format!("{a:?}"), format!("Identity({})", a.fingerprint()));
    }

    #[test]
    fn configs_build_with_alpn() {
        let id = Identity::generate().unwrap();
        let s = server_config(&id, &[ALPN_TCP]).unwrap();
        assert_eq!(s.alpn_protocols, vec![ALPN_TCP.to_vec()]);
        let c = client_config(id.fingerprint(), &[ALPN_QUIC]).unwrap();
        assert_eq!(c.alpn_protocols, vec![ALPN_QUIC.to_vec()]);
    }

    #[test]
    fn a_key_that_does_not_match_the_certificate_is_refused() {
        let a = Identity::generate().unwrap();
        let b = Identity::generate().unwrap();
        let mixed = Identity::from_der(a.cert_der().clone(), b.key_der().clone_key());
        assert!(server_config(&mixed, &[ALPN_QUIC]).is_err());
    }

    #[test]
    fn verifier_accepts_only_the_pinned_certificate() {
        let a = Identity::generate().unwrap();
        let b = Identity::generate().unwrap();
        let v = PinnedServerVerifier::new(a.fingerprint(), &provider());
        let name = ServerName::try_from(SERVER_NAME).unwrap();
        let now = UnixTime::now();
        assert!(v.verify_server_cert(a.cert_der(), &[], &name, &[], now).is_ok());
        assert!(v.rejected().is_none());
        assert!(v.verify_server_cert(b.cert_der(), &[], &name, &[], now).is_err());
        let text = v.rejected().expect("mismatch recorded").to_string();
        assert!(text.contains(&a.fingerprint().to_string()), "{text}");
        assert!(text.contains(&b.fingerprint().to_string()), "{text}");
    }
}
