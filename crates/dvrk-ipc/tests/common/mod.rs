//! Test helpers: an isolated iceoryx2 domain per test, removed on drop.
#![allow(dead_code)] // each test binary uses a different subset

use std::sync::atomic::{AtomicU32, Ordering};

use dvrk_ipc::iceoryx2::config::Config;
use dvrk_ipc::{ServiceNames, domain_config};

/// Short root path: the event socket path must stay below 108 bytes.
pub const ROOT: &str = "/tmp/iox2t/";

/// Env vars that hand a domain to a child process.
pub const ENV_DOMAIN: &str = "DVRK_IPC_TEST_DOMAIN";
pub const ENV_PREFIX: &str = "DVRK_IPC_TEST_PREFIX";

static COUNTER: AtomicU32 = AtomicU32::new(0);

/// An iceoryx2 domain (file prefix + root path) and a service prefix used by one test only.
pub struct Domain {
    pub domain_prefix: String,
    pub config: Config,
    pub names: ServiceNames,
    owner: bool,
}

impl Domain {
    /// A fresh domain, unique per process and call; cleaned up when dropped.
    pub fn new(test: &str) -> Self {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let domain_prefix = format!("t{}_{n}_", std::process::id());
        let config = domain_config(&domain_prefix, Some(ROOT)).expect("test domain");
        let names = ServiceNames::new(&format!("test/{test}")).expect("test prefix");
        Self {
            domain_prefix,
            config,
            names,
            owner: true,
        }
    }

    /// The domain handed over by the parent test process (not cleaned up by the child).
    pub fn from_env() -> Self {
        let domain_prefix = std::env::var(ENV_DOMAIN).expect(ENV_DOMAIN);
        let prefix = std::env::var(ENV_PREFIX).expect(ENV_PREFIX);
        Self {
            config: domain_config(&domain_prefix, Some(ROOT)).expect("child domain"),
            names: ServiceNames::new(&prefix).expect("child prefix"),
            domain_prefix,
            owner: false,
        }
    }

    /// Env vars for a child process that joins this domain.
    pub fn env(&self) -> [(&'static str, String); 2] {
        [
            (ENV_DOMAIN, self.domain_prefix.clone()),
            (ENV_PREFIX, self.names.prefix().to_owned()),
        ]
    }

    /// Files of this domain still present in /dev/shm and under the root path.
    pub fn leftovers(&self) -> Vec<std::path::PathBuf> {
        let mut found = Vec::new();
        collect(
            std::path::Path::new("/dev/shm"),
            &self.domain_prefix,
            &mut found,
        );
        collect(std::path::Path::new(ROOT), &self.domain_prefix, &mut found);
        found
    }
}

fn collect(dir: &std::path::Path, prefix: &str, out: &mut Vec<std::path::PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let name = e.file_name();
        if name.to_string_lossy().starts_with(prefix) {
            out.push(path);
        } else if path.is_dir() && !path.is_symlink() {
            collect(&path, prefix, out);
        }
    }
}

impl Drop for Domain {
    fn drop(&mut self) {
        if !self.owner {
            return;
        }
        for path in self.leftovers() {
            if path.is_dir() {
                let _ = std::fs::remove_dir_all(&path);
            } else {
                let _ = std::fs::remove_file(&path);
            }
            // Node directories are named by node id; remove them once our files are gone
            // (`remove_dir` fails on a directory another domain still uses).
            if let Some(parent) = path.parent()
                && parent.parent() == Some(std::path::Path::new(ROOT).join("nodes").as_path())
            {
                let _ = std::fs::remove_dir(parent);
            }
        }
    }
}

/// A prerequisite of a test is missing here: says so and lets the test return, except under CI
/// (`CI` set and not `0`/`false`, as .ci/run sets it), where .ci/run installs every
/// prerequisite and a missing one must fail instead of hiding as a pass.
pub fn skip_unless_ci(reason: &str) {
    let ci = std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "0" && v != "false");
    assert!(
        !ci,
        "{reason}: CI must run this test (.ci/run installs what it needs)"
    );
    println!("skipped: {reason}");
}
