//! `isin bench transports`: TCP against QUIC.

use clap::Args;

/// Arguments of `isin bench transports`.
#[derive(Args, Debug)]
pub struct TransportsArgs {}

/// Runs `isin bench transports`.
pub fn run(_args: TransportsArgs) -> anyhow::Result<()> {
    anyhow::bail!("not yet")
}
