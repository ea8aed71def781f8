//! Telling a person that a publisher went silent, once per episode.
//!
//! A [`dvrk_ipc::Subscription`] reports `Stale` after three missed periods (2 ms at 1500 Hz),
//! which is right for a controller but far too eager for a terminal: a slow or loaded publisher
//! would print a line every few milliseconds. This reports a silence once it lasts a second (or
//! the publisher is gone), and once more when samples flow again.

use dvrk_ipc::Update;

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
}

impl SilenceReporter {
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
                eprintln!("no publisher on {service}; waiting for one ...")
            }
            Notice::Silent { since_ns } => {
                eprintln!(
                    "no sample on {service} for {:.1} s; waiting ...",
                    since_ns as f64 * 1e-9
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
