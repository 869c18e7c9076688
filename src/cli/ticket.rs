//! Where a client finds its master: the join ticket from `--connect`, from a
//! file (`--ticket-file`) or from the environment (`ISIN_TICKET`), so that the
//! secret it carries need not stand on a command line for `ps` to show.

use anyhow::Context;
use clap::Args;
use isin_transport::{Ticket, TransportKind};
use std::path::{Path, PathBuf};

/// The environment variable a ticket is read from when neither `--connect`
/// nor `--ticket-file` is given.
pub const TICKET_ENV: &str = "ISIN_TICKET";

/// The longest ticket file read: a ticket is one short line.
const MAX_TICKET_FILE: u64 = 4096;

/// A viewer's offer to take its tiles straight from the slaves.
#[derive(Args, Debug, Clone, Default)]
pub struct DirectArgs {
    /// Take tiles straight from the slaves where they can reach this
    /// machine at HOST:PORT (port 0: any), not all through the master: for
    /// several viewers on a master whose link is the limit. The master still
    /// schedules every tile and checks a sample of them; a slave that cannot
    /// reach the address sends its tiles through the master.
    #[arg(long, value_name = "HOST:PORT")]
    pub direct: Option<String>,
}

/// The options naming a master, shared by every client command.
#[derive(Args, Debug, Clone)]
pub struct TicketArgs {
    /// The master's join ticket as it printed it (`isin://TOKEN@HOST:PORT?fp=…`,
    /// `isin+quic://…?fp=…`, or `isin+tcp-insecure://…`), or `HOST:PORT` with
    /// `--token` for a plaintext (`--insecure`) master. Without it (and without
    /// --ticket-file) the ticket is read from the ISIN_TICKET environment variable.
    #[arg(long, value_name = "TICKET", alias = "cluster", conflicts_with = "ticket_file")]
    pub connect: Option<String>,
    /// Read the ticket from this file (as `isin master --ticket-out` writes it),
    /// which keeps the secret out of the command line.
    #[arg(long, value_name = "PATH")]
    pub ticket_file: Option<PathBuf>,
    /// The shared secret, when the ticket is a bare `HOST:PORT` (a whole
    /// `isin+tcp-insecure://` ticket in a file keeps it off the command line).
    #[arg(long)]
    pub token: Option<String>,
    /// Transport, when the ticket is a bare `HOST:PORT`.
    #[arg(long, default_value = "tcp")]
    pub transport: TransportKind,
}

impl TicketArgs {
    /// The ticket, when one was given: `--connect`, else `--ticket-file`,
    /// else `ISIN_TICKET`; `None` when none of them is.
    pub fn ticket(&self) -> anyhow::Result<Option<Ticket>> {
        let (text, from) = if let Some(connect) = &self.connect {
            (connect.clone(), "--connect".to_string())
        } else if let Some(path) = &self.ticket_file {
            (read_ticket_file(path)?, path.display().to_string())
        } else {
            match std::env::var(TICKET_ENV) {
                Ok(s) if !s.trim().is_empty() => (s.trim().to_string(), TICKET_ENV.to_string()),
                Ok(_) | Err(std::env::VarError::NotPresent) => return Ok(None),
                Err(std::env::VarError::NotUnicode(_)) => anyhow::bail!("{TICKET_ENV} is not valid UTF-8"),
            }
        };
        let ticket = parse(&text, self.token.as_deref(), self.transport)
            .with_context(|| format!("the ticket from {from}"))?;
        Ok(Some(ticket))
    }

    /// [`TicketArgs::ticket`], required.
    pub fn require(&self) -> anyhow::Result<Ticket> {
        self.ticket()?.with_context(|| {
            format!("no master given: pass --connect TICKET or --ticket-file PATH, or set {TICKET_ENV}")
        })
    }
}

/// The ticket in a ticket file: its text without surrounding white space.
fn read_ticket_file(path: &Path) -> anyhow::Result<String> {
    use std::io::Read;
    let file =
        std::fs::File::open(path).with_context(|| format!("cannot read ticket file {}", path.display()))?;
    let mut text = String::new();
    file.take(MAX_TICKET_FILE + 1)
        .read_to_string(&mut text)
        .with_context(|| format!("cannot read ticket file {}", path.display()))?;
    anyhow::ensure!(
        text.len() as u64 <= MAX_TICKET_FILE,
        "ticket file {} is longer than {MAX_TICKET_FILE} bytes: a ticket is one line",
        path.display()
    );
    let ticket = text.trim();
    anyhow::ensure!(!ticket.is_empty(), "ticket file {} is empty", path.display());
    Ok(ticket.to_string())
}

/// A ticket as given: a full `isin://…` ticket (its token replaced by
/// `token` when given), or `HOST:PORT` with `token` for a plaintext master
/// (`transport` `tcp-insecure`; the encrypted transports need the whole
/// ticket, for its fingerprint).
pub fn parse(text: &str, token: Option<&str>, transport: TransportKind) -> anyhow::Result<Ticket> {
    if text.contains("://") {
        let mut t: Ticket = text.parse()?;
        if let Some(tok) = token {
            t.token = tok.to_string();
        }
        Ok(t)
    } else {
        let token = token.context("a bare HOST:PORT needs --token (or pass the whole isin:// ticket)")?;
        anyhow::ensure!(
            transport == TransportKind::TcpInsecure,
            "--transport {transport} needs the whole ticket the master printed (it carries the \
             certificate fingerprint); a bare HOST:PORT only reaches a plaintext master \
             (--transport tcp-insecure)"
        );
        Ok(Ticket { transport, token: token.to_string(), addr: text.to_string(), fingerprint: None })
    }
}

/// The command a slave joins `ticket` with, the ticket in single quotes so
/// that a shell (zsh globbing `?`, any shell splitting at `&`) passes it whole.
pub fn join_hint(ticket: &Ticket) -> String {
    format!("isin slave --connect {}", shell_quote(&ticket.to_string()))
}

/// `s` in single quotes for a POSIX shell (a `'` inside closed, escaped and reopened).
pub fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quoting_keeps_every_character_for_the_shell() {
        assert_eq!(shell_quote("isin://t@h:1?fp=ab&x"), "'isin://t@h:1?fp=ab&x'");
        assert_eq!(shell_quote("a'b"), r"'a'\''b'");
    }

    fn from_file(path: PathBuf) -> TicketArgs {
        TicketArgs { connect: None, ticket_file: Some(path), token: None, transport: TransportKind::Tcp }
    }

    #[test]
    fn ticket_files_are_trimmed_and_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let ok = dir.path().join("ticket");
        std::fs::write(&ok, "isin+tcp-insecure://tok@127.0.0.1:9\n").unwrap();
        let t = from_file(ok).require().unwrap();
        assert_eq!((t.token.as_str(), t.addr.as_str()), ("tok", "127.0.0.1:9"));

        let empty = dir.path().join("empty");
        std::fs::write(&empty, " \n").unwrap();
        let err = from_file(empty).require().unwrap_err();
        assert!(format!("{err:#}").contains("is empty"), "{err:#}");

        let big = dir.path().join("big");
        std::fs::write(&big, "x".repeat(MAX_TICKET_FILE as usize + 1)).unwrap();
        let err = from_file(big).require().unwrap_err();
        assert!(format!("{err:#}").contains("4096"), "{err:#}");
    }
}
