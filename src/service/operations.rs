//! Long-running onboardings: each runs on its own thread with a progress counter and a
//! cancel flag; clients poll (or watch) it by operation id. Finished operations are kept
//! (bounded) so their outcome can still be read.

use crate::store::ObjectInfo;
use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OperationState {
    Running,
    Succeeded,
    Failed,
    Cancelled,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct OperationStatus {
    pub id: String,
    pub object_id: String,
    pub state: OperationState,
    pub templates_done: u64,
    pub templates_total: u64,
    /// When failed: why.
    pub error: Option<String>,
    /// When succeeded: the stored object.
    pub object: Option<ObjectInfo>,
}

pub struct Operation {
    pub id: String,
    pub object_id: String,
    pub cancel: AtomicBool,
    pub done: AtomicU64,
    pub total: AtomicU64,
    outcome: Mutex<(OperationState, Option<String>, Option<ObjectInfo>)>,
}

impl Operation {
    pub fn status(&self) -> OperationStatus {
        let g = self.outcome.lock().expect("operation lock");
        OperationStatus {
            id: self.id.clone(),
            object_id: self.object_id.clone(),
            state: g.0.clone(),
            templates_done: self.done.load(Ordering::Relaxed),
            templates_total: self.total.load(Ordering::Relaxed),
            error: g.1.clone(),
            object: g.2.clone(),
        }
    }

    pub fn finish(&self, state: OperationState, error: Option<String>, object: Option<ObjectInfo>) {
        *self.outcome.lock().expect("operation lock") = (state, error, object);
    }

    pub fn is_running(&self) -> bool {
        self.outcome.lock().expect("operation lock").0 == OperationState::Running
    }
}

/// Finished operations remembered at most.
const KEEP_FINISHED: usize = 1000;

#[derive(Default)]
struct Registry {
    by_id: HashMap<String, Arc<Operation>>,
    /// Ids in start order, for forgetting the oldest finished ones.
    order: VecDeque<String>,
}

#[derive(Default)]
pub struct Operations {
    inner: Mutex<Registry>,
    counter: AtomicU64,
}

impl Operations {
    pub fn start(&self, object_id: &str, total: u64) -> Arc<Operation> {
        let n = self.counter.fetch_add(1, Ordering::Relaxed);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
        let id = format!("op-{:x}-{n}", nanos & 0xffff_ffff_ffff);
        let op = Arc::new(Operation {
            id: id.clone(),
            object_id: object_id.to_string(),
            cancel: AtomicBool::new(false),
            done: AtomicU64::new(0),
            total: AtomicU64::new(total),
            outcome: Mutex::new((OperationState::Running, None, None)),
        });
        let mut g = self.inner.lock().expect("operations lock");
        g.by_id.insert(id.clone(), op.clone());
        g.order.push_back(id);
        // Forget the oldest finished ones beyond the bound (running ones always stay).
        while g.order.len() > KEEP_FINISHED {
            let Some(pos) = g.order.iter().position(|i| g.by_id.get(i).is_none_or(|o| !o.is_running())) else { break };
            let old = g.order.remove(pos).expect("index valid");
            g.by_id.remove(&old);
        }
        op
    }

    pub fn get(&self, id: &str) -> Option<Arc<Operation>> {
        self.inner.lock().expect("operations lock").by_id.get(id).cloned()
    }

    /// Running operations, for the readiness of onboarding slots and for shutdown.
    pub fn running(&self) -> usize {
        self.inner.lock().expect("operations lock").by_id.values().filter(|o| o.is_running()).count()
    }

    /// Asks every running onboarding to stop (at shutdown); returns how many were asked.
    pub fn cancel_all(&self) -> usize {
        let g = self.inner.lock().expect("operations lock");
        g.by_id.values().filter(|o| o.is_running()).map(|o| o.cancel.store(true, Ordering::Relaxed)).count()
    }

    /// Whether an onboarding of `object_id` is under way.
    pub fn running_for(&self, object_id: &str) -> bool {
        self.inner.lock().expect("operations lock").by_id.values().any(|o| o.object_id == object_id && o.is_running())
    }
}
