//! Telling a person that a publisher went silent, once per episode.
//!
//! A [`dvrk_ipc::Subscription`] reports `Stale` after three missed periods (2 ms at 1500 Hz),
//! which is right for a controller but far too eager for a terminal: a slow or loaded publisher
//! would print a line every few milliseconds. This reports a silence once it lasts a second (or
//! the publisher is gone), and once more when samples flow again. When other accounts run a
//! sidecar of their own ([`dvrk_ipc::access::no_publisher_hint`]), the silence's line says so:
//! a service of another account is invisible from this one, which is the usual reason for a
//! consumer that never sees a sample.

use dvrk_ipc::Update;
use dvrk_ipc::iceoryx2::config::Config;

/// How long samples must be missing before a person is told.
pub const SILENCE_NS: u64 = 1_000_000_000;

/// What to say, if anything, after an update.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Notice {
    /// Nothing new to say.
    None,
    /// No sample for `since_ns`, or the publisher is gone (`since_ns` = 0).
    Silent { since_ns: u64 },
    /// Samples flow again after a reported silence.
    Back,
}

/// Remembers whether the current silence was already reported.
#[derive(Debug, Default)]
pub struct SilenceReporter {
    reported: bool,
    /// The domain the consumer looks in, for the hint about other accounts' sidecars.
    domain: Option<Config>,
}

impl SilenceReporter {
    /// A reporter whose silence line names other accounts' sidecars, if any, beside `domain`.
    pub fn for_domain(domain: &Config) -> Self {
        Self {
            reported: false,
            domain: Some(domain.clone()),
        }
    }

    /// The hint about other accounts' sidecars for this reporter's domain (none without one).
    fn hint(&self) -> String {
        self.domain
            .as_ref()
            .and_then(dvrk_ipc::access::no_publisher_hint)
            .map_or_else(String::new, |h| format!(" ({h})"))
    }

    pub fn update<T>(&mut self, update: &Update<T>) -> Notice {
        match update {
            Update::Fresh(_) if self.reported => {
                self.reported = false;
                Notice::Back
            }
            Update::Stale { since_ns } if !self.reported && *since_ns >= SILENCE_NS => {
                self.reported = true;
                Notice::Silent {
                    since_ns: *since_ns,
                }
            }
            Update::Terminated if !self.reported => {
                self.reported = true;
                Notice::Silent { since_ns: 0 }
            }
            _ => Notice::None,
        }
    }

    /// Prints the notice for `service` on stderr.
    pub fn report<T>(&mut self, update: &Update<T>, service: &str) {
        match self.update(update) {
            Notice::None => {}
            Notice::Silent { since_ns: 0 } => {
                eprintln!(
                    "no publisher on {service}; waiting for one ...{}",
                    self.hint()
                )
            }
            Notice::Silent { since_ns } => {
                eprintln!(
                    "no sample on {service} for {:.1} s; waiting ...{}",
                    since_ns as f64 * 1e-9,
                    self.hint()
                )
            }
            Notice::Back => eprintln!("samples on {service} flow again"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_silence_is_reported_once_after_a_second_and_its_end_once() {
        let mut r = SilenceReporter::default();
        let fresh = Update::Fresh(1u8);
        assert_eq!(r.update(&fresh), Notice::None);
        // Missed deadlines of a slow publisher: not worth a line.
        for ms in [2, 4, 500, 999] {
            assert_eq!(
                r.update(&Update::<u8>::Stale {
                    since_ns: ms * 1_000_000
                }),
                Notice::None
            );
        }
        assert_eq!(
            r.update(&Update::<u8>::Stale {
                since_ns: SILENCE_NS
            }),
            Notice::Silent {
                since_ns: SILENCE_NS
            }
        );
        assert_eq!(
            r.update(&Update::<u8>::Stale {
                since_ns: 2 * SILENCE_NS
            }),
            Notice::None
        );
        assert_eq!(r.update(&Update::<u8>::Terminated), Notice::None);
        assert_eq!(r.update(&fresh), Notice::Back);
        assert_eq!(r.update(&fresh), Notice::None);
        assert_eq!(
            r.update(&Update::<u8>::Terminated),
            Notice::Silent { since_ns: 0 }
        );
        assert_eq!(r.update(&Update::<u8>::Interrupted), Notice::None);
    }
}
