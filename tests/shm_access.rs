//! A consumer running as another user than the publisher: iceoryx2 0.10 refuses it (owner-only
//! modes), and dvrk-ipc must say so in words, naming the file and its owner, instead of
//! iceoryx2's bare `NodeCreationFailure::InternalError`. The project's default domain: a
//! consumer finds the service there, and `serve` refuses a directory another account owns.
//!
//! Real users, real shared memory: the test re-runs its own binary under `setpriv` as `nobody`
//! (the publisher's side: it creates the domain and the cycle event service) and as an unnamed
//! uid (the consumer). Needs root to switch users; ignored otherwise.

mod common;

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::Duration;

use common::{Proc, sidecar_bin, unique_prefix, write_config};

use dvrk_ipc::iceoryx2::service::ipc::Service;
use dvrk_ipc::{IpcError, ServiceNames, create_node, domain_config, open_cycle_event};

const ENV_ROLE: &str = "DVRK_SHM_ACCESS_ROLE";
const ENV_DOMAIN: &str = "DVRK_SHM_ACCESS_DOMAIN";
const PUBLISHER_UID: u32 = 65534;
const CONSUMER_UID: u32 = 65533;

fn root_path(domain: &str) -> String {
    format!("/tmp/iox2{domain}/")
}

/// Not a test on its own: what the child processes run.
#[test]
#[ignore = "child process role; run by consumer_of_another_user_is_told_why"]
fn child_role() {
    let (Ok(role), Ok(domain)) = (std::env::var(ENV_ROLE), std::env::var(ENV_DOMAIN)) else {
        return;
    };
    let cfg = domain_config(&domain, Some(&root_path(&domain))).unwrap();
    let names = ServiceNames::new("test/shm_access").unwrap();
    let result = create_node::<Service>(&format!("shm_access_{role}"), Some(&cfg))
        .and_then(|node| open_cycle_event(&node, &names).map(|event| (node, event)));
    match (role.as_str(), result) {
        ("publisher", Ok(_kept)) => {
            println!("ROLE ready");
            // Keep the node and the service until the parent closes stdin.
            let _ = std::io::stdin().read_line(&mut String::new());
        }
        (_, Ok(_)) => println!("ROLE ok"),
        (_, Err(e @ IpcError::PermissionDenied { .. })) => println!("ROLE denied {e}"),
        (_, Err(e)) => println!("ROLE other {e}"),
    }
}

fn spawn_as(uid: u32, role: &str, domain: &str) -> Child {
    Command::new("setpriv")
        .args([
            &format!("--reuid={uid}"),
            &format!("--regid={uid}"),
            "--clear-groups",
        ])
        .arg(std::env::current_exe().unwrap())
        .args(["child_role", "--exact", "--ignored", "--nocapture"])
        .env(ENV_ROLE, role)
        .env(ENV_DOMAIN, domain)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("setpriv")
}

/// The child's `ROLE ...` line (libtest may print before it on the same line); the rest of its
/// output is drained in the background so the child never writes into a closed pipe.
fn role_line(child: &mut Child) -> String {
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let found = lines
        .by_ref()
        .map_while(Result::ok)
        .find_map(|l| l.split_once("ROLE ").map(|(_, r)| r.to_owned()))
        .unwrap_or_default();
    std::thread::spawn(move || lines.for_each(drop));
    found
}

fn cleanup(domain: &str) {
    let _ = std::fs::remove_dir_all(root_path(domain));
    if let Ok(entries) = std::fs::read_dir("/dev/shm") {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(domain) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

#[cfg_attr(
    not(has_root),
    ignore = "needs root to run the publisher and the consumer as two other users (setpriv)"
)]
#[test]
fn consumer_of_another_user_is_told_why() {
    let domain = format!("hd{}_", std::process::id());
    cleanup(&domain);

    let mut publisher = spawn_as(PUBLISHER_UID, "publisher", &domain);
    let ready = role_line(&mut publisher);
    assert_eq!(
        ready, "ready",
        "the publisher (uid {PUBLISHER_UID}) did not start"
    );

    // Same user as the publisher: works (so the refusal below is about the user, nothing else).
    let mut same = spawn_as(PUBLISHER_UID, "consumer", &domain);
    let same_line = role_line(&mut same);
    let _ = same.wait();

    // Another user: refused, in words, with the file and its owner.
    let mut other = spawn_as(CONSUMER_UID, "consumer", &domain);
    let other_line = role_line(&mut other);
    let _ = other.wait();

    if let Some(mut stdin) = publisher.stdin.take() {
        let _ = stdin.write_all(b"\n");
    }
    let _ = publisher.wait();
    cleanup(&domain);

    assert_eq!(same_line, "ok", "a consumer of the publisher's own user");
    let msg = other_line
        .strip_prefix("denied ")
        .unwrap_or_else(|| panic!("expected a permission error, got: {other_line}"));
    let root = PathBuf::from(root_path(&domain));
    for needle in [
        "permission denied on the shared memory of the dVRK sidecar",
        "belongs to user nobody",
        "--user",
        root.to_str().unwrap().trim_end_matches('/'),
    ] {
        assert!(msg.contains(needle), "{needle:?} missing from: {msg}");
    }
    eprintln!("the consumer of uid {CONSUMER_UID} was told: {msg}");
}

/// Root in a domain that another account (the service's) created: refused before anything is
/// created there, in words naming the owner and what to run instead; the domain's files are
/// left as they were (nothing owned by root appears).
#[cfg_attr(
    not(has_root),
    ignore = "needs root to run the publisher as another user (setpriv) and to be root"
)]
#[test]
fn root_is_refused_in_the_services_domain_before_it_locks_the_service_out() {
    let domain = format!("hr{}_", std::process::id());
    cleanup(&domain);
    let mut publisher = spawn_as(PUBLISHER_UID, "publisher", &domain);
    let ready = role_line(&mut publisher);
    assert_eq!(
        ready, "ready",
        "the publisher (uid {PUBLISHER_UID}) did not start"
    );

    let cfg = domain_config(&domain, Some(&root_path(&domain))).unwrap();
    let r = create_node::<Service>("shm_access_root", Some(&cfg));
    let root_owned: Vec<PathBuf> = walk(&PathBuf::from(root_path(&domain)))
        .into_iter()
        .filter(|p| {
            std::os::unix::fs::MetadataExt::uid(&std::fs::symlink_metadata(p).unwrap()) == 0
        })
        .collect();

    if let Some(mut stdin) = publisher.stdin.take() {
        let _ = stdin.write_all(b"\n");
    }
    let _ = publisher.wait();
    cleanup(&domain);

    let e = match r {
        Err(e @ IpcError::RootWouldLockOut { .. }) => e.to_string(),
        Err(e) => panic!("expected the root refusal, got: {e}"),
        Ok(_) => panic!("root created a node in the domain of uid {PUBLISHER_UID}"),
    };
    for needle in ["you are root", "belongs to user nobody", "sudo -u nobody"] {
        assert!(e.contains(needle), "{needle:?} missing from: {e}");
    }
    assert!(root_owned.is_empty(), "root left files: {root_owned:?}");
}

/// Every path under `dir` (not following links).
fn walk(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let p = e.path();
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                out.extend(walk(&p));
            }
            out.push(p);
        }
    }
    out
}

/// `dvrk-sidecar CMD ARGS` with `DVRK_SIDECAR_IPC_ROOT` set to `root` (or removed for `None`,
/// the default domain), stdout and stderr captured.
fn sidecar(args: &[&str], root: Option<&Path>) -> Command {
    let mut c = Command::new(sidecar_bin());
    c.args(args)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    match root {
        Some(r) => c.env(dvrk_ipc::IPC_ROOT_ENV, r),
        None => c.env_remove(dvrk_ipc::IPC_ROOT_ENV),
    };
    c
}

/// `echo SERVICE --json --count N` in the domain of `root`: (exit status, stdout, stderr), or
/// a failed test when it does not end within 60 s (a liveness bound, not a speed claim).
fn echo(service: &str, count: u32, root: Option<&Path>) -> (ExitStatus, String, String) {
    let mut p = Proc::spawn(
        "echo",
        &mut sidecar(
            &["echo", service, "--json", "--count", &count.to_string()],
            root,
        ),
    );
    let mut out = p.child.as_mut().unwrap().stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut out, &mut s);
        s
    });
    let st = p
        .wait_timeout(Duration::from_secs(60))
        .unwrap_or_else(|| panic!("echo {service} did not end within 60 s"));
    let err = p.stderr_text();
    (st, reader.join().unwrap(), err)
}

/// The service on the built-in simulator, in the project's default domain (no
/// `DVRK_SIDECAR_IPC_ROOT`), and a consumer started the same way, as another program of the
/// account would be: the consumer finds it, and the domain's directory is the account's own
/// (`/tmp/dvrk-sidecar-<euid>/`, not writable by others) with its segments under the project's
/// prefix in /dev/shm.
#[test]
fn a_consumer_finds_the_service_in_the_default_domain() {
    let prefix = unique_prefix("shm_default");
    let cfg = write_config("shm_default", "sim", "shared", &prefix, "divot-push.toml");
    let mut serve = Proc::spawn(
        "serve",
        &mut sidecar(&["serve", "--config", cfg.to_str().unwrap()], None),
    );
    let (st, out, err) = echo(&format!("{prefix}/measured_js"), 5, None);
    let (serve_st, log) = serve.terminate();
    assert!(st.success(), "echo failed: {err}\nserve: {log}");
    let seqs: Vec<u64> = out
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["header"]["seq"]
                .as_u64()
                .unwrap()
        })
        .collect();
    assert_eq!(seqs.len(), 5, "{out}");
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{seqs:?}");
    assert!(serve_st.success(), "{log}");

    // SAFETY: geteuid has no preconditions.
    let uid = unsafe { libc::geteuid() };
    let root = PathBuf::from(format!("/tmp/dvrk-sidecar-{uid}"));
    let m = std::fs::symlink_metadata(&root).expect("the default root directory");
    assert!(m.is_dir());
    assert_eq!(std::os::unix::fs::MetadataExt::uid(&m), uid);
    let mode = std::os::unix::fs::MetadataExt::mode(&m) & 0o7777;
    assert_eq!(mode & 0o022, 0, "{} has mode {mode:04o}", root.display());
    let ours = format!("dvrk_{uid}_");
    let segments = std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(&ours))
        .count();
    assert!(segments > 0, "no /dev/shm/{ours}* segment");
}

/// `serve` refuses to start when its shared-memory directory (here moved with
/// `DVRK_SIDECAR_IPC_ROOT`) belongs to another account, which could hide the service from its
/// consumers: before creating anything there, naming the path, the owner, the mode and what
/// to do; a consumer pointed there gets the same words. Once the directory is its own, the
/// service starts there and a consumer with the same variable finds it.
#[cfg_attr(
    not(has_root),
    ignore = "skipped: needs root to give the directory to another account (chown to uid 65534)"
)]
#[test]
fn serve_refuses_a_shared_memory_directory_another_account_owns() {
    let root = PathBuf::from(format!("/tmp/iox2hs{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir(&root).unwrap();
    std::fs::set_permissions(&root, std::os::unix::fs::PermissionsExt::from_mode(0o700)).unwrap();
    std::os::unix::fs::chown(&root, Some(PUBLISHER_UID), Some(PUBLISHER_UID)).unwrap();

    let prefix = unique_prefix("shm_theirs");
    let cfg = write_config("shm_theirs", "sim", "shared", &prefix, "divot-push.toml");
    let serve_args = ["serve", "--config", cfg.to_str().unwrap()];
    let mut refused = Proc::spawn("serve", &mut sidecar(&serve_args, Some(&root)));
    let refused_st = refused.wait_timeout(Duration::from_secs(60));
    let refused_log = refused.stderr_text();
    let left: Vec<PathBuf> = walk(&root);
    let (echo_st, _, echo_err) = echo(&format!("{prefix}/measured_js"), 1, Some(&root));

    // Its own now: the service starts there, and a consumer told the same root finds it.
    std::os::unix::fs::chown(&root, Some(0), Some(0)).unwrap();
    let mut serve = Proc::spawn("serve", &mut sidecar(&serve_args, Some(&root)));
    let (st, out, err) = echo(&format!("{prefix}/measured_js"), 3, Some(&root));
    let (serve_st, log) = serve.terminate();
    let registered = walk(&root).len();
    let _ = std::fs::remove_dir_all(&root);

    let refused_st = refused_st.expect("serve did not stop within 60 s in a foreign directory");
    assert!(
        !refused_st.success(),
        "serve started in a directory of uid {PUBLISHER_UID}"
    );
    let owner = "nobody";
    for msg in [&refused_log, &echo_err] {
        for needle in [
            &format!(
                "refusing the dVRK sidecar's shared-memory directory {}",
                root.display()
            ),
            &format!(
                "belongs to another account (owner {owner}, mode 0700; this process runs as root)"
            ),
            &format!("sudo -u {owner}"),
            "sudo rm -rf",
            dvrk_ipc::IPC_ROOT_ENV,
        ] {
            assert!(msg.contains(needle), "{needle:?} missing from: {msg}");
        }
    }
    assert!(
        !echo_st.success(),
        "echo accepted the directory of uid {PUBLISHER_UID}"
    );
    assert!(left.is_empty(), "serve created files in it: {left:?}");
    eprintln!("serve was refused with: {refused_log}");

    assert!(
        st.success(),
        "echo in its own directory failed: {err}\nserve: {log}"
    );
    assert_eq!(out.lines().count(), 3, "{out}");
    assert!(serve_st.success(), "{log}");
    assert!(registered > 0, "nothing of iceoryx2 in {}", root.display());
}

/// A consumer that hears no publisher says why it may be (issue 22): other accounts' sidecar
/// roots exist, and a service of another account is invisible from this one. `echo` names them
/// in its silence line.
#[test]
fn a_consumer_that_hears_nobody_names_other_accounts_sidecars() {
    // SAFETY: geteuid cannot fail.
    let other = unsafe { libc::geteuid() }.wrapping_add(424_242);
    let dir = PathBuf::from(format!("/tmp/dvrk-sidecar-{other}"));
    let created = !dir.exists();
    std::fs::create_dir_all(&dir).unwrap();
    let arm = unique_prefix("hint");
    let service = format!("{arm}/measured_js");
    let mut p = Proc::spawn("echo", &mut sidecar(&["echo", &service], None));
    let err = p.child.as_mut().unwrap().stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            if line.contains("no sample on") || line.contains("no publisher on") {
                let _ = tx.send(line);
                return;
            }
        }
    });
    // echo reports a silence once it lasts a second; 60 s is a liveness bound.
    let line = rx.recv_timeout(Duration::from_secs(60));
    p.terminate();
    if created {
        let _ = std::fs::remove_dir(&dir);
    }
    let line = line.expect("echo said nothing about the silence within 60 s");
    assert!(line.contains(&service), "{line}");
    assert!(
        line.contains(&format!("{}/", dir.display())),
        "the other account's root is not named: {line}"
    );
    assert!(line.contains("run this program as"), "{line}");
}
