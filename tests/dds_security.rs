//! SROS2 (DDS Security) between the node and a Fast DDS peer (tests/fastdds/imu_peer.cpp on
//! Debian's libfastrtps 2.9, built with its security plugins), in a private network namespace:
//! a keystore made by scripts/sros2_keystore.sh, the node started as rcl starts a secured node
//! (`ROS_SECURITY_ENABLE`, `ROS_SECURITY_STRATEGY=Enforce`, `ROS_SECURITY_KEYSTORE`,
//! `--enclave`). See docs/interop.md, "Security".

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

use common::fastdds_peer::{self, run, Order, Prepared, Run, Setup, NODE_NAME};
use common::manifest_dir;
use common::replay_reference::imu_fields;

static SERIAL: Mutex<()> = Mutex::new(());

const COUNT: usize = 2000;

fn skip_or_fail(why: &str) {
    common::skip_or_fail("dds_security", why);
}

/// A keystore made by the project's script: `specs` are its ENCLAVE[:PUBLISH[:SUBSCRIBE]];
/// `data_protection` the governance's data_protection_kind (`ros2 security`'s is ENCRYPT).
fn keystore(dir: &Path, data_protection: &str, specs: &[&str]) -> PathBuf {
    let out = Command::new("bash")
        .env("SROS2_DATA_PROTECTION", data_protection)
        .arg(manifest_dir().join("scripts/sros2_keystore.sh"))
        .arg(dir)
        .args(specs)
        .output()
        .expect("bash");
    assert!(out.status.success(), "sros2_keystore.sh: {}", String::from_utf8_lossy(&out.stderr));
    dir.to_path_buf()
}

/// The node's security environment under Enforce, with this keystore.
fn enforced(keystore: &Path) -> Vec<(&'static str, String)> {
    vec![
        ("ROS_SECURITY_ENABLE", "true".into()),
        ("ROS_SECURITY_STRATEGY", "Enforce".into()),
        ("ROS_SECURITY_KEYSTORE", keystore.display().to_string()),
    ]
}

/// The Fast DDS test set-up, and two keystores of the robot's enclaves (the node's and the IMU
/// driver's): as `ros2 security` makes it, and with the payload not encrypted a second time
/// (the submessage still is).
struct Keystores {
    robot: PathBuf,
    robot_payload_clear: PathBuf,
}

fn prepare() -> Option<(Prepared, Keystores)> {
    if let Err(why) = Command::new("openssl").arg("version").output() {
        skip_or_fail(&format!("no openssl: {why}"));
        return None;
    }
    let p = fastdds_peer::prepare("dds_security", COUNT)?;
    // The driver may publish the IMU and call ~/adapt, and read the node's output and replies.
    let driver = format!("/imu_driver:rt/imu/data_raw,rq/{NODE_NAME}/adaptRequest:rt/imu/denoised,rr/{NODE_NAME}/adaptReply");
    let robot = keystore(&p.dir.path().join("keystore"), "ENCRYPT", &["/imu_fsda", &driver]);
    let robot_payload_clear = keystore(&p.dir.path().join("keystore_payload_clear"), "NONE", &["/imu_fsda", &driver]);
    Some((p, Keystores { robot, robot_payload_clear }))
}

fn secured_node(robot: &Path) -> Setup {
    Setup { node_env: enforced(robot), node_args: vec!["--enclave".into(), "/imu_fsda".into()], ..Setup::default() }
}

/// The node secured with its enclave, the driver with its own, under `ros2 security`'s
/// governance: 2000/2000 samples back, each equal to the offline replay's bits; /diagnostics
/// says security is on and with which enclave. The driver's `~/adapt` call is not answered
/// there: RustDDS 0.15.1 fails to decrypt a payload-encrypted request that carries Fast DDS's
/// inline QoS (its log: ring's "Unspecified" error; docs/interop.md, "Security"). Under the
/// same governance with the payload not encrypted a second time (the whole submessage still
/// is), the call is answered. Should the first call ever be answered, the limitation is gone:
/// update docs/interop.md and this test.
#[test]
fn a_secured_node_serves_the_peer_its_keystore_admits() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((p, keys)) = prepare() else { return };
    for (tag, keystore) in [("sros2_governance", &keys.robot), ("payload_clear", &keys.robot_payload_clear)] {
        let mut setup = secured_node(keystore);
        setup.peer_args = vec!["--security".into(), keystore.join("enclaves/imu_driver").display().to_string()];
        let r = run(&p.peer, p.dir.path(), tag, &p.slice, COUNT, Order::NodeFirst, &setup);
        let logs = &r.logs;
        assert_eq!(r.rc, vec![0, 0], "{tag}: peer / node exit codes\n{logs}");
        assert_eq!((r.summary("matched"), r.summary("sent")), (1, COUNT as u64), "{tag}\n{logs}");
        assert_eq!(r.denoised.len(), COUNT, "{tag}: /imu/denoised messages the secured peer got\n{logs}");
        for (i, ((stamp, _, bits), want)) in r.denoised.iter().zip(&p.reference.denoised).enumerate() {
            let want: Vec<u64> = imu_fields(want).iter().flat_map(|(_, v)| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>()).collect();
            assert_eq!(bits, &want, "{tag}: #{i} (stamp {stamp}): over secured DDS != replay");
        }
        let security = r.node_stats["security"].as_str().unwrap_or_default();
        assert!(security.starts_with("on: enclave /imu_fsda") && security.ends_with("Enforce"), "{}", r.node_stats);
        let answered = tag == "payload_clear";
        assert_eq!((r.summary("called"), r.summary("replied")), (1, u64::from(answered)), "{tag}: the ~/adapt call\n{logs}");
        eprintln!(
            "dds_security {tag}: {COUNT}/{COUNT} through the secured node, bit-equal to replay (matched after {} s)",
            r.summary["match_s"]
        );
    }
}

/// What a stranger gets from the secured node: nothing. The peer tries for 8 s to match, then
/// publishes its 2000 samples and calls `~/adapt` all the same; the node, run as in the test
/// above, must have received no sample and no call, and the stranger no output and no reply.
fn assert_shut_out(r: &Run, who: &str) {
    let logs = &r.logs;
    assert_eq!(r.summary("sent"), COUNT as u64, "{who}: the stranger tried\n{logs}");
    assert_eq!((r.summary("matched"), r.summary("reader_matched")), (0, 0), "{who} matched the node\n{logs}");
    assert_eq!(r.denoised.len(), 0, "{who} read /imu/denoised\n{logs}");
    assert_eq!((r.summary("called"), r.summary("replied")), (1, 0), "{who}'s ~/adapt call\n{logs}");
    assert_eq!(r.node_stats["counters"]["received"].as_u64(), Some(0), "{who}'s samples reached the node: {}", r.node_stats);
    assert!(r.node_stats["adapt_requested_by"].as_str().unwrap_or_default().is_empty(), "{who} called ~/adapt: {}", r.node_stats);
}

/// A peer without security (plain DDS, as a node of an unsecured stack) and a peer with a
/// keystore of its own (its identity and permissions signed by another CA) are both shut out.
#[test]
fn a_secured_node_accepts_nothing_from_a_stranger() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((p, keys)) = prepare() else { return };
    let stranger = ["--match-timeout-s", "8", "--send-unmatched", "1"].map(String::from).to_vec();
    let mut setup = secured_node(&keys.robot);
    setup.peer_args = stranger.clone();
    let plain = run(&p.peer, p.dir.path(), "plain_peer", &p.slice, COUNT, Order::NodeFirst, &setup);
    assert_shut_out(&plain, "a peer without security");

    let foreign = keystore(&p.dir.path().join("foreign"), "ENCRYPT", &["/imu_driver"]);
    setup.peer_args = [stranger, vec!["--security".into(), foreign.join("enclaves/imu_driver").display().to_string()]].concat();
    let other_ca = run(&p.peer, p.dir.path(), "other_ca_peer", &p.slice, COUNT, Order::NodeFirst, &setup);
    assert_shut_out(&other_ca, "a peer of another CA");
}

/// Under Enforce, an enclave the keystore does not hold, a governance changed after it was
/// signed, or an identity another CA signed stops the node at start with the reason; it never
/// runs on plain DDS.
#[test]
fn an_enforced_node_without_valid_files_does_not_start() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((p, keys)) = prepare() else { return };
    // A copy of the robot's keystore whose node enclave lost its integrity, one way each.
    let broken = |tag: &str, damage: &dyn Fn(&Path)| {
        let ks = p.dir.path().join(tag);
        let out = Command::new("cp").arg("-r").arg(&keys.robot).arg(&ks).output().expect("cp");
        assert!(out.status.success(), "cp: {}", String::from_utf8_lossy(&out.stderr));
        damage(&ks.join("enclaves/imu_fsda"));
        ks
    };
    let tampered = broken("tampered", &|enclave| {
        let g = enclave.join("governance.p7s");
        let text = std::fs::read_to_string(&g).unwrap();
        assert!(text.contains("<enable_join_access_control>true"), "the governance as signed");
        std::fs::write(&g, text.replace("<enable_join_access_control>true", "<enable_join_access_control>false")).unwrap();
    });
    let foreign = keystore(&p.dir.path().join("foreign_ca"), "ENCRYPT", &["/imu_fsda"]);
    let impostor = broken("impostor", &|enclave| {
        std::fs::copy(foreign.join("enclaves/imu_fsda/cert.pem"), enclave.join("cert.pem")).unwrap();
        std::fs::copy(foreign.join("enclaves/imu_fsda/key.pem"), enclave.join("key.pem")).unwrap();
    });
    let cases: [(&str, &Path, &str, &str); 3] = [
        ("no_enclave", &keys.robot, "/not_in_the_keystore", "not_in_the_keystore does not exist"),
        ("tampered_governance", &tampered, "/imu_fsda", "Validating local permissions failed"),
        ("identity_of_another_ca", &impostor, "/imu_fsda", "does not verify against identity CA"),
    ];
    for (tag, keystore, enclave, why) in cases {
        let mut setup = secured_node(keystore);
        setup.node_args = vec!["--enclave".into(), enclave.into()];
        setup.peer_args = ["--match-timeout-s", "3"].map(String::from).to_vec();
        let r = run(&p.peer, p.dir.path(), tag, &p.slice, COUNT, Order::NodeFirst, &setup);
        assert_ne!(r.rc.get(1), Some(&0), "{tag}: the node must not run\n{}", r.logs);
        assert_eq!(r.summary("matched"), 0, "{tag}\n{}", r.logs);
        let said = r.logs.contains(why) && (tag != "no_enclave" || r.logs.contains("does not start on plain DDS"));
        assert!(said, "{tag}: the reason, said at start\n{}", r.logs);
    }
}
