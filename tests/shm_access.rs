//! A consumer running as another user than the publisher: iceoryx2 0.10 refuses it (owner-only
//! modes), and dvrk-ipc must say so in words, naming the file and its owner, instead of
//! iceoryx2's bare `NodeCreationFailure::InternalError`.
//!
//! Real users, real shared memory: the test re-runs its own binary under `setpriv` as `nobody`
//! (the publisher's side: it creates the domain and the cycle event service) and as an unnamed
//! uid (the consumer). Needs root to switch users; ignored otherwise.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

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

/// `serve` refuses to publish into a shared-memory directory that another account created
/// first (it could hide the service from its consumers), naming the owner and what to do, and
/// starts once the directory is its own.
#[cfg_attr(
    not(has_root),
    ignore = "needs root to give the directory to another user (chown)"
)]
#[test]
fn the_service_refuses_a_domain_directory_another_account_created() {
    let domain = format!("hs{}_", std::process::id());
    cleanup(&domain);
    let root = PathBuf::from(root_path(&domain));
    std::fs::create_dir_all(&root).unwrap();
    std::os::unix::fs::chown(&root, Some(PUBLISHER_UID), Some(PUBLISHER_UID)).unwrap();
    let cfg = domain_config(&domain, Some(&root_path(&domain))).unwrap();
    let e = dvrk_ipc::access::refuse_domain_of_another(&cfg)
        .expect_err("a directory of uid 65534 accepted for a service of uid 0")
        .to_string();
    std::os::unix::fs::chown(&root, Some(0), Some(0)).unwrap();
    let ok = dvrk_ipc::access::refuse_domain_of_another(&cfg);
    cleanup(&domain);
    for needle in [
        "belongs to user nobody",
        "not to this service's account (root)",
        "sudo rm -rf",
    ] {
        assert!(e.contains(needle), "{needle:?} missing from: {e}");
    }
    assert!(ok.is_ok(), "its own directory refused: {ok:?}");
}
