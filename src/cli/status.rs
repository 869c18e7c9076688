//! `isin status TICKET`: what a cluster is doing — its slaves, clients and
//! batch jobs, as the master reports them.

use super::cluster;
use clap::Args;
use isin_actors::client::{self, HANDSHAKE_TIMEOUT};
use isin_cluster::protocol::{DEFAULT_MAX_FRAME, Message, Status};
use isin_cluster::scheduler::Work;
use std::fmt::Write;

/// Arguments of `isin status`.
#[derive(Args, Debug)]
pub struct StatusArgs {
    /// The join ticket the master printed (`isin://TOKEN@HOST:PORT?fp=…`);
    /// without it, `--ticket-file` or `ISIN_TICKET`.
    #[arg(value_name = "TICKET")]
    pub ticket: Option<String>,
    /// Where else the ticket may come from.
    #[command(flatten)]
    pub cluster: super::ticket::TicketArgs,
}

/// Runs `isin status`.
pub fn run(args: StatusArgs) -> anyhow::Result<()> {
    let ticket = match &args.ticket {
        Some(t) => super::ticket::parse(t, args.cluster.token.as_deref(), args.cluster.transport)?,
        None => args.cluster.require()?,
    };
    let transport = cluster::client_transport(&ticket)?;
    let status = actix::System::new().block_on(async {
        let join = client::Join::viewer("status", Work::Batch);
        let (mut conn, _) = client::handshake(transport.as_ref(), &ticket, join).await?;
        client::send_message(&conn, &Message::StatusRequest)?;
        loop {
            match client::recv_message(&mut conn, DEFAULT_MAX_FRAME, HANDSHAKE_TIMEOUT).await? {
                Message::Status(s) => {
                    conn.sender.close();
                    return anyhow::Ok(s);
                }
                Message::Error { message } => anyhow::bail!("the master says: {message}"),
                _ => {}
            }
        }
    })?;
    print!("{}", report(&status));
    Ok(())
}

/// The status as `isin status` prints it.
pub fn report(s: &Status) -> String {
    let mut out = String::new();
    let plural = |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
    let _ = writeln!(out, "{}", plural(s.slaves.len(), "slave", "slaves"));
    for x in &s.slaves {
        let _ = writeln!(
            out,
            "  {:<24} {:>3} threads  {:>8.1} tiles/s  last seen {} ms ago",
            x.name, x.threads, x.tiles_per_second, x.last_seen_ms
        );
    }
    let _ = writeln!(out, "{}", plural(s.clients.len(), "client", "clients"));
    for c in &s.clients {
        let work = match c.work {
            Work::Interactive => "interactive",
            Work::Batch => "batch",
        };
        let _ = writeln!(
            out,
            "  {:<24} {:<11}  {} open, {} done",
            c.name,
            work,
            plural(c.open_frames as usize, "frame", "frames"),
            c.frames_done
        );
    }
    let _ = writeln!(out, "{}", plural(s.jobs.len(), "job", "jobs"));
    for j in &s.jobs {
        let eta = match j.eta_seconds {
            Some(t) if j.done < j.frames => format!(", ETA {t:.0} s"),
            _ => String::new(),
        };
        let state = if j.done >= j.frames {
            "finished"
        } else if j.running {
            "running"
        } else {
            "waiting for its client"
        };
        let _ = writeln!(out, "  {:<24} {}/{} frames, {state}{eta}", j.name, j.done, j.frames);
    }
    let _ = writeln!(out, "{}", plural(s.scenes as usize, "scene held", "scenes held"));
    let _ = writeln!(out, "{} scene bytes sent to slaves", s.scene_bytes_sent);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_cluster::protocol::{ClientStatus, JobStatus, SlaveStatus};

    #[test]
    fn the_report_names_every_slave_client_and_job_with_its_progress() {
        let s = Status {
            slaves: vec![SlaveStatus {
                id: 3,
                name: "attic#3".into(),
                threads: 8,
                tiles_per_second: 41.5,
                last_seen_ms: 120,
            }],
            clients: vec![ClientStatus {
                id: 4,
                name: "fly#4".into(),
                work: Work::Batch,
                open_frames: 1,
                frames_done: 7,
            }],
            jobs: vec![JobStatus {
                name: "out/".into(),
                done: 7,
                frames: 30,
                running: true,
                eta_seconds: Some(46.0),
            }],
            scenes: 2,
            scene_bytes_sent: 123_456,
        };
        let r = report(&s);
        assert!(r.starts_with("1 slave\n"), "{r}");
        assert!(r.contains("attic#3") && r.contains("8 threads") && r.contains("41.5 tiles/s"), "{r}");
        assert!(r.contains("fly#4") && r.contains("batch") && r.contains("1 frame open"), "{r}");
        assert!(r.contains("7/30 frames, running, ETA 46 s"), "{r}");
        assert!(r.ends_with("2 scenes held\n123456 scene bytes sent to slaves\n"), "{r}");
    }
}
