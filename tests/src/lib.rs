//! Workspace-level tests: Meso's code against values derived independently of it
//! (the scripts that made them and their outputs live in tests/reference/), and,
//! as render modes arrive, image regressions against golden references.

#[cfg(test)]
mod architecture;
#[cfg(test)]
mod biscale;
#[cfg(test)]
mod brdf_reference;
#[cfg(test)]
mod fuzz;
#[cfg(test)]
mod golden;
#[cfg(test)]
mod metrics_reference;
#[cfg(test)]
mod regress;
#[cfg(test)]
mod scenes;
#[cfg(test)]
mod shipped_packs;
