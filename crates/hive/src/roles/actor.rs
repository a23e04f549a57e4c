//! The actor role.
use anyhow::{Result, bail};
use crate::RoleArgs;
pub fn run(_role: RoleArgs, _env: usize) -> Result<()> { bail!("not built yet") }
