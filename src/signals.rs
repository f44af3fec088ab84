//! Stopping a run cleanly on a signal: SIGINT (Ctrl-C), SIGTERM (what `timeout`, systemd,
//! Docker and batch schedulers send) and SIGHUP (a closed terminal) all ask the run to stop
//! after the current frame, so that what is done is written; a second signal quits at once.
//! The exit status then follows the shell's convention, 128 + the signal's number.

use std::io;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The signals that stop a run.
#[cfg(unix)]
pub(crate) const STOP_SIGNALS: [i32; 3] = [
    signal_hook::consts::SIGINT,
    signal_hook::consts::SIGTERM,
    signal_hook::consts::SIGHUP,
];

/// A stop flag raised by `STOP_SIGNALS`, and which signal raised it.
#[derive(Debug, Clone)]
pub struct StopSignals {
    stop: Arc<AtomicBool>,
    which: Arc<AtomicUsize>,
}

impl StopSignals {
    /// Installs the handlers (once per process).
    pub fn install() -> io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let which = Arc::new(AtomicUsize::new(0));
        #[cfg(unix)]
        for sig in STOP_SIGNALS {
            // The first signal raises the flag; one that finds it raised ends the process.
            signal_hook::flag::register_conditional_shutdown(sig, 128 + sig, stop.clone())?;
            signal_hook::flag::register_usize(sig, which.clone(), sig as usize)?;
            signal_hook::flag::register(sig, stop.clone())?;
        }
        #[cfg(not(unix))]
        {
            let (s, w) = (stop.clone(), which.clone());
            ctrlc::set_handler(move || {
                w.store(2, Ordering::SeqCst);
                if s.swap(true, Ordering::SeqCst) {
                    std::process::exit(130);
                }
            })
            .map_err(io::Error::other)?;
        }
        Ok(StopSignals { stop, which })
    }

    /// The flag the run polls between frames.
    pub fn flag(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// The signal that asked the run to stop, if one did.
    pub fn received(&self) -> Option<i32> {
        match self.which.load(Ordering::SeqCst) {
            0 => None,
            s => Some(s as i32),
        }
    }

    /// The exit status of a run a signal stopped: 128 + the signal (130 for SIGINT, 143 for
    /// SIGTERM, 129 for SIGHUP); 130 when the run stopped for another reason.
    pub fn exit_code(&self) -> i32 {
        128 + self.received().unwrap_or(2)
    }
}

/// The signal's name, for messages.
pub fn name(sig: i32) -> &'static str {
    match sig {
        1 => "SIGHUP",
        2 => "SIGINT",
        15 => "SIGTERM",
        _ => "a signal",
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    /// One test touches the process's handlers (tests run in threads of one process).
    #[test]
    fn sigterm_and_sighup_stop_as_sigint_does() {
        let s = StopSignals::install().unwrap();
        assert_eq!(s.received(), None);
        assert!(!s.flag().load(Ordering::SeqCst));
        signal_hook::low_level::raise(signal_hook::consts::SIGTERM).unwrap();
        assert!(s.flag().load(Ordering::SeqCst));
        assert_eq!(s.received(), Some(15));
        assert_eq!(s.exit_code(), 143);
        assert_eq!(name(15), "SIGTERM");
        assert_eq!(name(1), "SIGHUP");
    }
}
