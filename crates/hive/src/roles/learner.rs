//! The learner role.
use anyhow::{Result, bail};
use crate::RoleArgs;
pub fn run(_role: RoleArgs) -> Result<()> { bail!("not built yet") }
pub fn bench(_t: usize, _b: usize, _u: usize, _j: bool) -> Result<()> { bail!("not built yet") }
