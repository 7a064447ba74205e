//! Helpers shared by the integration tests: the venv's Python for the independent readers, and
//! for the DDS tests (tests/dds_interop.rs, tests/dds_adapt.rs) the prerequisites check (venv
//! with cyclonedds, a network namespace), process guards, and running a script inside a fresh
//! network + PID namespace (only `lo`, multicast on).
#![allow(dead_code)] // each test binary uses a different subset

use std::ffi::OsStr;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

pub mod fastdds_peer;
pub mod python_peer;
pub mod random_model;
pub mod replay_reference;

pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_imu-fsda")
}

pub fn manifest_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The project's venv Python (`PYTHON`, else the one scripts/setup.sh makes) with the
/// independent readers' packages; `None` after a loud skip, a failure under CI.
pub fn venv_python() -> Option<PathBuf> {
    let p = std::env::var_os("PYTHON").map(PathBuf::from).unwrap_or_else(|| {
        let cache = std::env::var_os("XDG_CACHE_HOME")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache"));
        cache.join("imu-fsda/torch-2.13.0/bin/python")
    });
    if p.exists() {
        Some(p)
    } else {
        assert!(std::env::var_os("CI").is_none(), "python venv missing in CI: {}", p.display());
        eprintln!("SKIPPED: {} not found (run scripts/setup.sh)", p.display());
        None
    }
}

/// Not runnable here: skip loudly, or fail under CI.
pub fn skip_or_fail(test: &str, why: &str) {
    if std::env::var_os("CI").is_some() {
        panic!("{test} cannot run, and CI is set: {why}");
    }
    // Straight to the process's stderr: libtest captures `eprintln!` of passing tests.
    let _ = writeln!(std::io::stderr(), "SKIPPED: {test}: {why}");
}

/// A child process (and its process group) that is killed when dropped: no orphans when an
/// assertion or a timeout ends the test early.
pub struct Guarded {
    pub child: Child,
    what: String,
}

impl Guarded {
    pub fn spawn(cmd: &mut Command, what: &str) -> Guarded {
        use std::os::unix::process::CommandExt;
        cmd.process_group(0);
        let child = cmd.spawn().unwrap_or_else(|e| panic!("{what}: cannot start {cmd:?}: {e}"));
        Guarded { child, what: what.to_string() }
    }

    /// Wait at most `timeout`; `None` (after killing everything) when it ran out.
    pub fn wait_timeout(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let t0 = Instant::now();
        loop {
            if let Some(st) = self.child.try_wait().expect("try_wait") {
                return Some(st);
            }
            if t0.elapsed() > timeout {
                self.kill();
                return None;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn kill(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            eprintln!("killing {} (pid {})", self.what, self.child.id());
            // The whole process group; `unshare --kill-child` + the PID namespace take the rest.
            let _ = Command::new("kill").args(["-KILL", "--", &format!("-{}", self.child.id())]).status();
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

impl Drop for Guarded {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Runs `cmd` to completion; panics with its stderr on failure, else returns the stderr.
pub fn ok(cmd: &mut Command) -> String {
    let o = cmd.output().expect("spawn imu-fsda");
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{cmd:?} failed:\n{err}");
    err
}

/// `imu-fsda eval BAG --method power-on-bias EXTRA…`: the one row of its `--json` (written in `dir`).
pub fn eval_power_on_bias(bag: &Path, extra: &[&OsStr], dir: &Path) -> Value {
    let json = dir.join("eval.json");
    ok(Command::new(bin()).arg("eval").arg(bag).args(["--method", "power-on-bias"]).args(extra).arg("--json").arg(&json));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("eval wrote its --json")).expect("eval's --json parses");
    v["rows"][0].clone()
}

/// Run `imu-fsda args` to completion within `timeout`, output captured; panics with it on failure.
pub fn run_cli(args: &[&str], what: &str, timeout: Duration) -> String {
    let mut cmd = Command::new(bin());
    cmd.args(args).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    let mut g = Guarded::spawn(&mut cmd, what);
    // Read the pipes on threads so a chatty child cannot block on a full pipe.
    let mut so = g.child.stdout.take().unwrap();
    let mut se = g.child.stderr.take().unwrap();
    let ho = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut so, &mut s);
        s
    });
    let he = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut se, &mut s);
        s
    });
    let st = g.wait_timeout(timeout);
    let (out, err) = (ho.join().unwrap(), he.join().unwrap());
    match st {
        Some(s) if s.success() => out,
        Some(s) => panic!("{what}: imu-fsda {args:?} failed ({s}):\n{out}\n{err}"),
        None => panic!("{what}: imu-fsda {args:?} did not finish within {timeout:?}:\n{out}\n{err}"),
    }
}

/// What a DDS test needs from the machine; `Err` = skip (or fail under CI).
pub struct Prereqs {
    pub python: PathBuf,
}

pub fn prerequisites() -> Result<Prereqs, String> {
    let python = std::env::var_os("PYTHON").map(PathBuf::from).unwrap_or_else(|| {
        let venv = std::env::var_os("IMU_FSDA_VENV").map(PathBuf::from).unwrap_or_else(|| {
            let cache = std::env::var_os("XDG_CACHE_HOME")
                .map(PathBuf::from)
                .unwrap_or_else(|| PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache"));
            cache.join("imu-fsda/torch-2.13.0")
        });
        venv.join("bin/python")
    });
    let ok = Command::new(&python)
        .args(["-c", "import cyclonedds, importlib.metadata as m; assert m.version('cyclonedds') == '11.0.1', m.version('cyclonedds')"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        return Err(format!("{} has no cyclonedds==11.0.1 (run scripts/setup.sh, or set PYTHON)", python.display()));
    }
    // The exact namespace recipe the tests use, with nothing in it.
    let ns = Command::new("unshare")
        .args(["--net", "--pid", "--fork", "--kill-child", "bash", "-c", LO_SETUP])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output();
    match ns {
        Ok(o) if o.status.success() => {}
        Ok(o) => {
            return Err(format!(
                "cannot create a network namespace with multicast on lo (needs root, unshare, ip): {}",
                String::from_utf8_lossy(&o.stderr).trim()
            ))
        }
        Err(e) => return Err(format!("cannot run unshare: {e}")),
    }
    Ok(Prereqs { python })
}

/// Loopback up with multicast (discovery ~0.1 s; without it rustdds falls back to unicast
/// after ~7.6 s, toolchain.md).
pub const LO_SETUP: &str = "ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo";

/// ../shared/data (the real EuRoC and TUM-VI recordings); `None` after a loud skip, a
/// failure under CI.
pub fn shared_data() -> Option<PathBuf> {
    let p = manifest_dir().join("../shared/data");
    if p.join("euroc").is_dir() && p.join("tumvi").is_dir() {
        Some(p)
    } else {
        assert!(std::env::var_os("CI").is_none(), "../shared/data is missing in CI");
        eprintln!("SKIPPED: ../shared/data not found; the real-data tests need it");
        None
    }
}

/// The folder `mav0/` of an EuRoC sequence: `preferred`, else the first of the fallbacks found.
pub fn euroc_sequence(preferred: &str, fallbacks: &[&str]) -> Result<PathBuf, String> {
    let root = manifest_dir().join("../shared/data/euroc");
    std::iter::once(&preferred)
        .chain(fallbacks)
        .map(|s| root.join(s).join("mav0"))
        .find(|p| p.join("imu0/data.csv").is_file())
        .ok_or_else(|| format!("no EuRoC sequence under {}", root.display()))
}

/// Runs `script` (bash, after `set -u` and the loopback set-up; exit 90 = set-up failed)
/// with `args` as `$1…`, inside a fresh network + PID namespace, within `timeout`.
/// ROS / Cyclone environment variables that could widen the network are removed.
/// `None` when it ran out of time (everything in it is killed).
pub fn run_in_namespace(script: &str, args: &[&str], envs: &[(&str, &OsStr)], timeout: Duration) -> (Option<ExitStatus>, f64) {
    let full = format!("set -u\n{LO_SETUP} || exit 90\n{script}");
    let mut cmd = Command::new("unshare");
    cmd.args(["--net", "--pid", "--fork", "--kill-child", "bash", "-c", &full, "bash"])
        .args(args)
        .env("IMU_FSDA_BIN", bin())
        .env("ROS_DOMAIN_ID", "0")
        .env_remove("ROS_LOCALHOST_ONLY")
        .env_remove("ROS_AUTOMATIC_DISCOVERY_RANGE")
        .env_remove("CYCLONEDDS_URI")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    for (k, v) in envs {
        cmd.env(k, v);
    }
    let t0 = Instant::now();
    let mut g = Guarded::spawn(&mut cmd, "namespace run");
    let st = g.wait_timeout(timeout);
    (st, t0.elapsed().as_secs_f64())
}

pub fn tail(s: &str, n: usize) -> String {
    let lines: Vec<&str> = s.lines().collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// A float64 from a peer's JSON (its bit pattern as 16 hex digits).
pub fn f(v: &Value) -> f64 {
    f64::from_bits(u64::from_str_radix(v.as_str().expect("hex float"), 16).expect("hex float"))
}

pub fn fs(v: &Value) -> Vec<f64> {
    v.as_array().expect("float array").iter().map(f).collect()
}

/// Bitwise float comparison (the same f64 inputs through the same code must give the same
/// bits; −0.0 ≠ 0.0 here on purpose).
pub fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

pub fn stamp_ns(h: &Value) -> i64 {
    h["sec"].as_i64().unwrap() * 1_000_000_000 + h["nanosec"].as_i64().unwrap()
}

/// The last line of `stdout` that parses as JSON (a node's `--stats-json`).
pub fn last_json_line(stdout: &str) -> Option<Value> {
    stdout.lines().rev().find_map(|l| serde_json::from_str(l).ok())
}
