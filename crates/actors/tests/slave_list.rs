//! The master tells its viewers which slaves it has: when a viewer joins, and
//! again whenever a slave joins or dies.

use isin_actors::client;
use isin_actors::master::{Master, MasterConfig};
use isin_actors::viewer::{self, GetSlaves, SlaveList, ViewerActor};
use isin_cluster::codec::Codec;
use isin_cluster::protocol::{Message, SlaveEntry};
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use isin_transport::Ticket;
use isin_transport::Transport;
use isin_transport::mem::MemTransport;
use std::time::Duration;

/// Waits (up to 10 s) for a slave list that `want` accepts.
async fn wait_list(
    v: &actix::Addr<ViewerActor>,
    what: &str,
    want: impl Fn(&[SlaveEntry]) -> bool,
) -> SlaveList {
    for _ in 0..2000 {
        let list = v.send(GetSlaves).await.unwrap();
        if list.slaves.as_deref().is_some_and(&want) {
            return list;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("never got a slave list with {what}: {:?}", v.send(GetSlaves).await.unwrap());
}

/// A slave by hand: authenticates, takes the scene, says it is ready; the
/// connection is returned so the test can close it (a slave dying).
async fn fake_slave(
    t: &MemTransport,
    ticket: &Ticket,
    name: &str,
    threads: u32,
) -> isin_transport::Connection {
    let (mut conn, welcome) =
        client::handshake(t, ticket, client::Join::slave(name, threads, &[], &[Codec::Raw])).await.unwrap();
    let hash = welcome.scene.expect("a default scene").hash;
    isin_actors::slave::receive_scene(&mut conn, hash).await.unwrap();
    client::send_message(&conn, &Message::Ready { hash: Some(hash) }).unwrap();
    conn
}

#[actix::test]
async fn viewers_get_the_slave_list_on_joining_and_on_every_join_and_death() {
    let t = MemTransport::new();
    let bundle = SceneBundle { name: "fake.toml".into(), source: "fake".into(), ..Default::default() };
    let settings = RenderSettings { width: 32, height: 32, ..RenderSettings::default() };
    let cfg = MasterConfig::new("tok".into(), bundle, Camera::default(), settings).unwrap();
    let _master = Master::new(cfg).unwrap().serve(t.listen("master").await.unwrap());
    let ticket =
        // The kind is not read: the test hands the in-memory transport to the peer itself.
        Ticket { transport: isin_transport::TransportKind::TcpInsecure, token: "tok".into(), addr: "master".into(), fingerprint: None };

    // A slave that is there before the viewer.
    let first = fake_slave(&t, &ticket, "first", 3).await;
    let (v, _, _events) = viewer::connect(&t, &ticket, "gui").await.unwrap();
    let list = wait_list(&v, "the first slave", |s| s.len() == 1).await;
    let one = &list.slaves.as_ref().unwrap()[0];
    assert!(one.name.starts_with("first#") && one.alive && one.threads == 3, "{one:?}");
    assert!(!one.addr.is_empty(), "{one:?}");
    // A second one joins: the viewer hears of it without asking for a frame.
    let second = fake_slave(&t, &ticket, "second", 1).await;
    let list = wait_list(&v, "two live slaves", |s| s.len() == 2 && s.iter().all(|e| e.alive)).await;
    let ids: Vec<u64> = list.slaves.as_ref().unwrap().iter().map(|e| e.id).collect();
    assert_ne!(ids[0], ids[1]);
    // The first dies (its connection closes): listed as dead, the other alive.
    first.sender.close();
    let list = wait_list(&v, "a dead slave", |s| s.iter().any(|e| !e.alive)).await;
    let slaves = list.slaves.unwrap();
    let dead: Vec<&SlaveEntry> = slaves.iter().filter(|e| !e.alive).collect();
    let live: Vec<&SlaveEntry> = slaves.iter().filter(|e| e.alive).collect();
    assert_eq!(dead.len(), 1);
    assert!(dead[0].name.starts_with("first#"), "{slaves:?}");
    assert_eq!(live.len(), 1);
    assert!(live[0].name.starts_with("second#"), "{slaves:?}");
    assert!(list.version >= 3, "an update per change: {}", list.version);
    drop(second);
}
