//! A store that reads and never writes: what the replicas of a deployment use when they
//! share one store that an onboarding job (or a single writer server) fills.

use super::{ObjectInfo, ObjectStore, StoreError};
use crate::onboard::ObjectModel;
use std::sync::Arc;

pub struct ReadOnlyStore {
    inner: Arc<dyn ObjectStore>,
}

impl ReadOnlyStore {
    pub fn new(inner: Arc<dyn ObjectStore>) -> Self {
        Self { inner }
    }
}

impl ObjectStore for ReadOnlyStore {
    fn put(&self, _: &ObjectModel, _: bool) -> Result<ObjectInfo, StoreError> {
        Err(StoreError::ReadOnly(self.inner.url()))
    }

    fn get(&self, id: &str) -> Result<ObjectModel, StoreError> {
        self.inner.get(id)
    }

    fn list(&self) -> Result<Vec<ObjectInfo>, StoreError> {
        self.inner.list()
    }

    fn info(&self, id: &str) -> Result<ObjectInfo, StoreError> {
        self.inner.info(id)
    }

    fn delete(&self, _: &str) -> Result<(), StoreError> {
        Err(StoreError::ReadOnly(self.inner.url()))
    }

    fn exists(&self, id: &str) -> Result<bool, StoreError> {
        self.inner.exists(id)
    }

    fn generation(&self, id: &str) -> Result<Option<u64>, StoreError> {
        self.inner.generation(id)
    }

    fn url(&self) -> String {
        self.inner.url()
    }
}
