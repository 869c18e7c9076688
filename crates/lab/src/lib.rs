//! The benchmark lab behind `isin bench`: the bench drivers ([`bench`]) and
//! the emulated PCs they run on ([`netlab`]: network namespaces, rate-limited
//! links, CPU quotas). The drivers start the `isin` binary itself as masters
//! and slaves (the running executable, `std::env::current_exe`), so this
//! crate is only ever called from inside `isin`.

pub mod bench;
pub mod client;
pub mod netlab;
