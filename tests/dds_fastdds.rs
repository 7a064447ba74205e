//! The live node against a Fast DDS peer: tests/fastdds/imu_peer.cpp on Debian's libfastrtps
//! 2.9 (rmw_fastrtps's middleware, the default of ROS 2 Humble and Jazzy), with ROS 2's topic
//! and type names and a driver's sensor-data QoS, in a private network namespace (only `lo`).
//! See docs/interop.md.
//!
//! The peer is built here from its source with the system's g++ and Fast DDS headers
//! (scripts/setup.sh installs `libfastrtps-dev`); a machine without them skips loudly, a
//! failure under `CI`.

mod common;

use std::sync::Mutex;

use common::fastdds_peer::{prepare, run, Order, Setup};
use common::replay_reference::imu_fields;

static SERIAL: Mutex<()> = Mutex::new(());

const COUNT: usize = 2000;

/// A Fast DDS driver that starts publishing a second after it matched the node: all 2000
/// samples come back on /imu/denoised, every float equal to the offline replay's bits, and the
/// node's sequence-number counters show nothing lost; a `~/adapt` call made as rmw_fastrtps
/// makes it (request id in the related sample identity) is answered and matched to the call.
#[test]
fn a_fast_dds_peer_gets_every_sample_back_as_replay_computes_it() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(common::fastdds_peer::Prepared { peer, dir, slice, reference }) = prepare("dds_fastdds", COUNT) else { return };
    let r = run(&peer, dir.path(), "node_first", &slice, COUNT, Order::NodeFirst, &Setup::default());
    let logs = &r.logs;
    assert_eq!(r.rc, vec![0, 0], "peer / node exit codes\n{logs}");
    assert_eq!(r.summary("matched"), 1, "{logs}");
    assert_eq!(r.summary("sent"), COUNT as u64, "{logs}");
    assert_eq!(r.denoised.len(), COUNT, "/imu/denoised messages the Fast DDS reader got\n{logs}");
    for (i, ((stamp, frame, bits), want)) in r.denoised.iter().zip(&reference.denoised).enumerate() {
        assert_eq!(*stamp, want.header.stamp.to_ns(), "#{i}: stamp");
        assert_eq!(frame, "imu_link", "#{i}: frame_id");
        let want: Vec<u64> = imu_fields(want).iter().flat_map(|(_, v)| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>()).collect();
        assert_eq!(bits, &want, "#{i} (stamp {stamp}): over Fast DDS != replay");
    }
    assert_eq!(r.node_stats["counters"]["received"].as_u64(), Some(COUNT as u64), "{}", r.node_stats);
    assert_eq!((r.node("input_writers"), r.node("input_published_before_first"), r.node("input_lost")), (1, 0, 0), "{}", r.node_stats);
    // `~/adapt` called as rmw_fastrtps calls a service, answered and matched to the call.
    assert_eq!((r.summary("called"), r.summary("replied"), r.summary("reply_success")), (1, 1, 0), "{logs}");
    let message = &r.summary["reply_message"];
    assert!(message.starts_with("cannot adapt: no model is loaded"), "{message}");
    let caller = r.node_stats["adapt_requested_by"].as_str().unwrap_or_default();
    assert!(caller.starts_with("client "), "the node names its caller: {}", r.node_stats);
    eprintln!(
        "dds_fastdds: {COUNT}/{COUNT} through the node from Fast DDS, bit-equal to replay (peer matched after {} s)",
        r.summary["match_s"]
    );
}

/// A Fast DDS driver already publishing-ready when the node starts (a robot stack brings its
/// IMU driver up first) publishes the moment its writer matched: RustDDS can drop Fast DDS's
/// first discovery data (it arrives before Fast DDS's participant announcement is processed)
/// and match the writer only a second later (docs/interop.md), so the samples of that second
/// never reach the node. Whatever the race does, every sample is accounted for: what the node
/// received, plus what the writer's sequence numbers say it published before its first sample
/// arrived, plus the gaps after it, is what the peer sent; every sample received is answered,
/// but for answers the node published before its writer had matched the peer's reader (it
/// counts them: `denoised_published_before_a_reader`).
#[test]
fn samples_a_fast_dds_peer_published_before_the_match_are_counted() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(common::fastdds_peer::Prepared { peer, dir, slice, .. }) = prepare("dds_fastdds", COUNT) else { return };
    let mut before = Vec::new();
    for k in 0..3 {
        let r = run(&peer, dir.path(), &format!("peer_first_{k}"), &slice, COUNT, Order::PeerFirst, &Setup::default());
        let logs = &r.logs;
        assert_eq!(r.rc, vec![0, 0], "run {k}: peer / node exit codes\n{logs}");
        assert_eq!(r.summary("sent"), COUNT as u64, "{logs}");
        let received = r.node_stats["counters"]["received"].as_u64().unwrap_or_else(|| panic!("{}", r.node_stats));
        let (b, lost) = (r.node("input_published_before_first"), r.node("input_lost"));
        assert_eq!(received + b + lost, COUNT as u64, "run {k}: received {received} + before the first {b} + lost {lost}\n{logs}");
        // Every sample received is answered; an answer published before the node's writer had
        // matched the peer's reader (counted by the node) is, by volatile durability, for
        // nobody. The count is taken from the node's graph, which hears of a match just after
        // the writer makes it: it can count an answer that did arrive, never miss one that did not.
        let (answered, unheard) = (r.denoised.len() as u64, r.node("denoised_published_before_a_reader"));
        assert!(
            answered <= received && answered + unheard >= received,
            "run {k}: {answered} answers for {received} samples received, {unheard} published before a reader\n{logs}"
        );
        before.push(b);
    }
    eprintln!("dds_fastdds: the driver up first, samples it published before the first reached the node: {before:?} of {COUNT}");
}
