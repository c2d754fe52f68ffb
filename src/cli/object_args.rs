//! The options that name an onboarded object and the backbone to query it with, shared by
//! the commands that estimate (`estimate`, `track`).

use crate::onboard::ObjectModel;
use anyhow::{Context, Result};

#[derive(clap::Args, Debug)]
pub struct StoredObjectArgs {
    #[command(flatten)]
    pub backbone: super::backbone_args::BackboneArgs,
    /// Object store the object was onboarded into (default: $B2TF_STORE, else
    /// sqlite://~/.local/share/b2tfpose/objects.db).
    #[arg(long)]
    pub store: Option<String>,
    /// Id of the onboarded object.
    #[arg(long)]
    pub object: String,
}

impl StoredObjectArgs {
    /// The object, loaded from its store.
    pub fn load(&self) -> Result<ObjectModel> {
        let store = crate::store::open(&self.store.clone().unwrap_or_else(crate::store::default_url))?;
        store.get(&self.object).with_context(|| format!("loading object {:?} from {}", self.object, store.url()))
    }
}
