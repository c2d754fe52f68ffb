//! `b2tf objects list|show|delete`: what an object store holds.

use anyhow::Result;
use clap::{Args, Subcommand};
use std::time::Instant;

#[derive(Args, Debug)]
pub struct ObjectsArgs {
    /// Object store: sqlite://PATH.db or dir://PATH (default: $B2TF_STORE, else
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
            println!("| id | units | diameter (mm) | backbone | templates | MB | created (unix s) |");
            println!("|---|---|---:|---|---:|---:|---:|");
            for o in list {
                println!("| {} | {} | {:.1} | {} | {} | {:.1} | {} |", o.id, o.units.as_str(), o.diameter_m * 1e3, o.backbone.name, o.templates, o.bytes as f64 / 1e6, o.created_at);
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
    }
    Ok(())
}
