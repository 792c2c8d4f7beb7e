//! Temporary output files are removed when the process is interrupted.
//!
//! Outputs are written to a temporary file beside their destination and
//! renamed when complete ([`crate::output`]). A temporary file's `Drop`
//! removes it on every normal path, but SIGINT (Ctrl-C), SIGTERM or SIGHUP
//! end the process without running destructors: the paths of the temporary
//! files being written are therefore registered here, and on the first such
//! signal a watcher thread removes them, then restores the signal's default
//! action and raises it again, so that the process still ends *by* that
//! signal (a shell loop around `phasekit` stops on Ctrl-C as it should).
//!
//! The signal handler itself only writes the signal's number to a pipe (the
//! one async-signal-safe thing it needs); everything else runs on the watcher
//! thread. SIGKILL cannot be caught: a temporary file may then stay behind
//! (named `.NAME.XXXXXX.tmp` beside the destination).

use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Temporary files being written.
static TEMPORARIES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Creates a temporary file with `create` (which returns it and its path) and
/// registers it for removal on interruption, installing the handlers the first
/// time. The registry is locked while the file is created, so that a signal
/// arriving meanwhile removes it too (the cleanup waits for the lock).
pub fn create_registered<T>(
    create: impl FnOnce() -> std::io::Result<(T, PathBuf)>,
) -> std::io::Result<(T, PathBuf)> {
    install();
    let mut registry = TEMPORARIES.lock().unwrap_or_else(|p| p.into_inner());
    let (t, path) = create()?;
    registry.push(path.clone());
    Ok((t, path))
}

/// Forgets a temporary file (renamed into place, or removed).
pub fn unregister(path: &Path) {
    if let Ok(mut v) = TEMPORARIES.lock() {
        if let Some(i) = v.iter().rposition(|p| p == path) {
            v.swap_remove(i);
        }
    }
}

/// Removes every registered temporary file.
fn remove_all() {
    // The lock is only ever held for a push or a removal: never across a wait.
    let paths = match TEMPORARIES.lock() {
        Ok(mut v) => std::mem::take(&mut *v),
        Err(p) => std::mem::take(&mut *p.into_inner()),
    };
    for p in paths {
        let _ = std::fs::remove_file(p);
    }
}

#[cfg(unix)]
fn install() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(unix::install);
}

#[cfg(not(unix))]
fn install() {}

#[cfg(unix)]
mod unix {
    use std::sync::atomic::{AtomicI32, Ordering};

    /// The write end of the pipe the handler signals through (−1 before install).
    static PIPE_WRITE: AtomicI32 = AtomicI32::new(-1);

    const SIGNALS: [libc::c_int; 3] = [libc::SIGINT, libc::SIGTERM, libc::SIGHUP];

    extern "C" fn on_signal(sig: libc::c_int) {
        let fd = PIPE_WRITE.load(Ordering::Relaxed);
        let byte = sig as u8;
        // SAFETY: write(2) is async-signal-safe; `byte` outlives the call and the
        // length is 1. A failed write cannot be reported from here and is ignored.
        unsafe {
            libc::write(fd, (&byte as *const u8).cast(), 1);
        }
    }

    pub(super) fn install() {
        let mut fds = [0 as libc::c_int; 2];
        // SAFETY: `fds` is a valid array of two ints for pipe(2) to fill.
        if unsafe { libc::pipe(fds.as_mut_ptr()) } != 0 {
            return; // No pipe, no cleanup on signals: outputs stay correct, a temporary may remain.
        }
        let (read_fd, write_fd) = (fds[0], fds[1]);
        PIPE_WRITE.store(write_fd, Ordering::Relaxed);
        let spawned = std::thread::Builder::new()
            .name("phasekit-interrupt".into())
            .spawn(move || watch(read_fd));
        if spawned.is_err() {
            return;
        }
        for sig in SIGNALS {
            // SAFETY: a zeroed sigaction is a valid value to fill in; the handler
            // only calls write(2) on a descriptor that stays open for the life of
            // the process; SA_RESTART keeps interrupted reads and writes going.
            unsafe {
                let mut action: libc::sigaction = std::mem::zeroed();
                action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as usize;
                action.sa_flags = libc::SA_RESTART;
                libc::sigemptyset(&mut action.sa_mask);
                libc::sigaction(sig, &action, std::ptr::null_mut());
            }
        }
    }

    /// Waits for a signal's number, removes the temporary files, then dies of that signal.
    fn watch(read_fd: libc::c_int) {
        let mut byte = 0u8;
        loop {
            // SAFETY: reads at most one byte into `byte`, which outlives the call.
            let n = unsafe { libc::read(read_fd, (&mut byte as *mut u8).cast(), 1) };
            if n == 1 {
                break;
            }
            if n == 0 {
                return;
            }
        }
        super::remove_all();
        let sig = byte as libc::c_int;
        // SAFETY: restoring the default action and raising the signal ends the
        // process as the signal would have without a handler.
        unsafe {
            libc::signal(sig, libc::SIG_DFL);
            libc::raise(sig);
        }
        // Should the signal be blocked on this thread, end with the shell's convention.
        std::process::exit(128 + sig);
    }
}
