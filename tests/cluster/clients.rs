//! Several clients on one cluster at once, over real sockets.
//!
//! - `two_viewers_flying_at_once…`: two viewers, each requesting a new frame
//!   as soon as its last one is done (as a flying viewer does), neither
//!   cancelling the other: both get every frame, byte-identical to
//!   `isin render`, and when the first has all its frames the other has at
//!   least two thirds of its own (each viewer ≥ 40 % of the cluster).

use super::util::{Cluster, Transport, assert_same_pixels, client_transport, render_local};
use isin_actors::viewer;
use isin_transport::Ticket;
use std::sync::Mutex;

/// Frames each viewer flies.
const FRAMES: usize = 6;

cluster_test!(two_viewers_flying_at_once_each_get_their_frames_and_a_fair_share, |t| {
    let c = Cluster::start(t, 2, &[]);
    let local = render_local(&["--width", "128", "--height", "96"]);
    let ticket: Ticket = c.ticket.parse().expect("ticket");
    let transport = client_transport(&c);
    // Frames each viewer has, and the other's count when the first finished.
    let done = Mutex::new([0usize; 2]);
    let other_at_first_finish = Mutex::new(None);
    let (left, right) = actix::System::new().block_on(async {
        let fly = |me: usize, name: &'static str| {
            let (transport, ticket, done, other) = (&transport, &ticket, &done, &other_at_first_finish);
            async move {
                let (v, scene, mut events) =
                    viewer::connect(transport.as_ref(), ticket, name).await.expect("viewer");
                let scene = scene.expect("the master serves a scene");
                let settings = isin_tracer::RenderSettings { width: 128, height: 96, ..scene.settings };
                let mut got = Vec::new();
                for _ in 0..FRAMES {
                    let (frame, _) = viewer::collect_frame(&v, &mut events, scene.camera, settings)
                        .await
                        .expect("a frame");
                    got.push(frame.rgb);
                    done.lock().unwrap()[me] += 1;
                }
                let theirs = done.lock().unwrap()[1 - me];
                other.lock().unwrap().get_or_insert(theirs);
                got
            }
        };
        tokio::join!(fly(0, "left"), fly(1, "right"))
    });
    for rgb in left.iter().chain(&right) {
        assert_same_pixels(rgb, &local, "a flying viewer's frame vs isin render");
    }
    let other = other_at_first_finish.into_inner().unwrap().expect("someone finished");
    assert!(other * 3 >= FRAMES * 2, "when one viewer had its {FRAMES} frames, the other had {other}");
});
