//! `b2tf objects list|show|delete`: what an object store holds.

use anyhow::Result;
use clap::{Args, Subcommand};
use std::time::Instant;

#[derive(Args, Debug)]
pub struct ObjectsArgs {
    /// Object store: sqlite://PATH.db, dir://PATH or s3://BUCKET/PREFIX (default: $B2TF_STORE, else
    /// sqlite://~/.local/share/b2tfpose/objects.db).
    #[arg(long, global = true)]
    pub store: Option<String>,
    #[command(subcommand)]
    pub command: ObjectsCommand,
}

#[derive(Subcommand, Debug)]
pub enum ObjectsCommand {
    /// One line per stored object.
    List {
        /// JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// One object's record as JSON; with --load, also loads it whole (checks it decodes).
    Show {
        id: String,
        #[arg(long)]
        load: bool,
    },
    /// Removes an object.
    Delete { id: String },
    /// Brings objects stored by an older version up to the current model format: computes
    /// what they lack (the contour model, the detector's templates) from their stored mesh
    /// and writes them back, without re-onboarding. Default: every object in the store.
    Upgrade { ids: Vec<String> },
}

pub fn run(a: ObjectsArgs) -> Result<()> {
    let store = crate::store::open(&a.store.unwrap_or_else(crate::store::default_url))?;
    match a.command {
        ObjectsCommand::List { json } => {
            let list = store.list()?;
            if json {
                println!("{}", serde_json::to_string_pretty(&list)?);
                return Ok(());
            }
            println!("{}: {} objects", store.url(), list.len());
            println!("| id | units | diameter (mm) | backbone | templates | MB | created (unix s) | symmetries |");
            println!("|---|---|---:|---|---:|---:|---:|---|");
            for o in list {
                let symmetries = o.symmetries.as_ref().map_or_else(|| "unknown (objects upgrade finds them)".to_string(), |s| s.describe());
                println!("| {} | {} | {:.1} | {} | {} | {:.1} | {} | {symmetries} |", o.id, o.units.as_str(), o.diameter_m * 1e3, o.backbone.name, o.templates, o.bytes as f64 / 1e6, o.created_at);
            }
        }
        ObjectsCommand::Show { id, load } => {
            let info = store.info(&id)?;
            let mut v = serde_json::to_value(&info)?;
            if load {
                let t = Instant::now();
                let m = store.get(&id)?;
                v["loaded"] = serde_json::json!({"seconds": t.elapsed().as_secs_f64(), "patches": m.patch_count(), "memory_bytes": m.memory_bytes()});
            }
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        ObjectsCommand::Delete { id } => {
            store.delete(&id)?;
            println!("deleted {id:?} from {}", store.url());
        }
        ObjectsCommand::Upgrade { ids } => upgrade(store.as_ref(), ids)?,
    }
    Ok(())
}

fn upgrade(store: &dyn crate::store::ObjectStore, ids: Vec<String>) -> Result<()> {
    let ids = if ids.is_empty() { store.list()?.into_iter().map(|o| o.id).collect() } else { ids };
    let renderer = super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?;
    for id in ids {
        let mut m = store.get(&id)?;
        let lacked: Vec<&str> = [("contour model", m.contours.get().is_none()), ("detector templates", m.detector.get().is_none()), ("symmetries", m.symmetries.is_none())].iter().filter(|(_, missing)| *missing).map(|(what, _)| *what).collect();
        if lacked.is_empty() {
            println!("{id}: up to date");
            continue;
        }
        let t = Instant::now();
        if m.symmetries.is_none() {
            m.symmetries = Some(crate::onboard::mesh_symmetries(&m.mesh));
        }
        m.contour_model_or_build(&renderer)?;
        m.shape_model_or_build(&renderer)?;
        store.put(&m, true)?;
        println!("{id}: added {} in {:.1} s", lacked.join(" and "), t.elapsed().as_secs_f64());
    }
    Ok(())
}
