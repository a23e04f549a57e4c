//! The replay role.
use anyhow::{Result, bail};
use crate::RoleArgs;
pub fn run(_role: RoleArgs) -> Result<()> { bail!("not built yet") }
