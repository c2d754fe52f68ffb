//! The open tracking sessions (HTTP session resources and gRPC `Track` streams alike):
//! bounded in number (429 / RESOURCE_EXHAUSTED beyond), one frame at a time each (a second
//! frame sent while one is being processed is refused rather than queued, so a client
//! cannot grow the server's memory), and expired when idle. A stream's session lives
//! exactly as long as its stream; the sweeper leaves those alone.

use super::error::{ErrorKind, ServiceError};
use crate::track::TrackSession;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub struct SessionEntry<S = TrackSession> {
    pub id: String,
    pub session: Mutex<S>,
    busy: AtomicBool,
    last_used: Mutex<Instant>,
    /// Owned by a gRPC stream, which closes it when it ends (never expired by the sweeper).
    pub streamed: bool,
}

impl<S> SessionEntry<S> {
    pub fn idle(&self) -> Duration {
        self.last_used.lock().expect("session clock").elapsed()
    }
}

/// The right to process one frame of a session; frees the session on drop.
pub struct FrameTurn<S = TrackSession>(Arc<SessionEntry<S>>);

impl<S> FrameTurn<S> {
    pub fn entry(&self) -> &SessionEntry<S> {
        &self.0
    }
}

impl<S> Drop for FrameTurn<S> {
    fn drop(&mut self) {
        *self.0.last_used.lock().expect("session clock") = Instant::now();
        self.0.busy.store(false, Ordering::Release);
    }
}

pub struct TrackSessions<S = TrackSession> {
    open: Mutex<HashMap<String, Arc<SessionEntry<S>>>>,
    pub max_sessions: usize,
    pub idle_timeout: Duration,
}

impl<S> TrackSessions<S> {
    pub fn new(max_sessions: usize, idle_timeout: Duration) -> Self {
        Self { open: Mutex::new(HashMap::new()), max_sessions, idle_timeout }
    }

    fn map(&self) -> std::sync::MutexGuard<'_, HashMap<String, Arc<SessionEntry<S>>>> {
        self.open.lock().expect("sessions lock")
    }

    /// Registers a new session, after expiring idle ones; refused when `max_sessions` are
    /// open.
    pub fn open(&self, session: S, streamed: bool) -> Result<Arc<SessionEntry<S>>, ServiceError> {
        self.sweep();
        let mut map = self.map();
        if map.len() >= self.max_sessions {
            return Err(ServiceError::new(ErrorKind::ResourceExhausted, format!("{} tracking sessions are open (the limit); close one or retry later", map.len())));
        }
        let id = format!("trk-{}", crate::store::unique_suffix());
        let entry = Arc::new(SessionEntry { id: id.clone(), session: Mutex::new(session), busy: AtomicBool::new(false), last_used: Mutex::new(Instant::now()), streamed });
        map.insert(id, entry.clone());
        Ok(entry)
    }

    pub fn get(&self, id: &str) -> Result<Arc<SessionEntry<S>>, ServiceError> {
        self.map().get(id).cloned().ok_or_else(|| ServiceError::not_found(format!("tracking session {id:?} not found (closed, expired after {} s idle, or never opened)", self.idle_timeout.as_secs())))
    }

    /// The session's turn for one frame, or RESOURCE_EXHAUSTED while another frame of it is
    /// being processed.
    pub fn turn(&self, id: &str) -> Result<FrameTurn<S>, ServiceError> {
        let entry = self.get(id)?;
        if entry.busy.compare_exchange(false, true, Ordering::AcqRel, Ordering::Acquire).is_err() {
            return Err(ServiceError::new(ErrorKind::ResourceExhausted, format!("tracking session {id:?} is processing a frame: send its frames one at a time, each after the last one's answer")));
        }
        Ok(FrameTurn(entry))
    }

    pub fn close(&self, id: &str) -> Result<(), ServiceError> {
        self.map().remove(id).map(|_| ()).ok_or_else(|| ServiceError::not_found(format!("tracking session {id:?} not found")))
    }

    /// Closes the sessions idle for longer than the timeout (not streams, not one busy
    /// with a frame); returns how many.
    pub fn sweep(&self) -> usize {
        let mut map = self.map();
        let before = map.len();
        map.retain(|_, e| e.streamed || e.busy.load(Ordering::Acquire) || e.idle() <= self.idle_timeout);
        before - map.len()
    }

    pub fn list(&self) -> Vec<Arc<SessionEntry<S>>> {
        let mut v: Vec<_> = self.map().values().cloned().collect();
        v.sort_by(|a, b| a.id.cmp(&b.id));
        v
    }

    pub fn count(&self) -> usize {
        self.map().len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limit_turns_expiry_and_close() {
        let sessions: TrackSessions<()> = TrackSessions::new(2, Duration::from_millis(30));
        let a = sessions.open((), false).unwrap();
        let s = sessions.open((), true).unwrap();
        let full = sessions.open((), false).map(|_| ()).unwrap_err();
        assert_eq!(full.kind, ErrorKind::ResourceExhausted);
        assert!(full.message.contains("2 tracking sessions"), "{}", full.message);

        // One frame at a time per session; the turn frees it.
        let turn = sessions.turn(&a.id).unwrap();
        let busy = sessions.turn(&a.id).map(|_| ()).unwrap_err();
        assert_eq!(busy.kind, ErrorKind::ResourceExhausted);
        assert!(busy.message.contains("one at a time"), "{}", busy.message);
        assert!(sessions.turn(&s.id).is_ok(), "another session is not held up");

        // Idle past the timeout: a busy session and a stream's stay, the rest go.
        std::thread::sleep(Duration::from_millis(60));
        assert_eq!(sessions.sweep(), 0, "busy and streamed sessions are kept");
        drop(turn);
        assert_eq!(sessions.sweep(), 0, "a turn just ended counts as use");
        std::thread::sleep(Duration::from_millis(60));
        assert_eq!(sessions.sweep(), 1);
        let gone = sessions.get(&a.id).map(|_| ()).unwrap_err();
        assert_eq!(gone.kind, ErrorKind::NotFound);
        assert!(gone.message.contains("expired"), "{}", gone.message);
        assert_eq!(sessions.count(), 1);
        sessions.close(&s.id).unwrap();
        assert_eq!(sessions.close(&s.id).unwrap_err().kind, ErrorKind::NotFound);
        assert_eq!(sessions.list().len(), 0);
    }
}
