//! The light a front end asks for, checked with the flag named in every message
//! ([`LightSettings`]): the light model (`--light`), whether its LB light comes from base
//! solutions (`--basis`), how they combine for a sun (`--sun-weights`, `--ambient`), the coarse
//! global or forest grid (`--global-grid`, `--no-global`) and how base solutions are stored
//! (`--codec`, `--basis-precision`); and the warning before a coarse grid far costlier than
//! the default's ([`costly_grid_warning`]).

use sylva_geom::Scene;
use sylva_lb::relight::{Codec, CompressTarget, Precision};
use sylva_light::lighting::Light;
use sylva_light::relight::{GlobalGridOptions, PhysicalTarget, SunWeights};

use crate::{uses_forest, BasisUse, RelightPlan};

/// An option the pipeline refuses; the message names the flag.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct OptionError(pub String);

fn refuse(message: String) -> OptionError {
    OptionError(message)
}

/// Whether the LB light of plants comes from base solutions (`--basis`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BasisChoice {
    /// Base solutions when every model's are cached (the physical light's or the paper
    /// light's), else solved for the sun; the SPP light solves for the sun.
    Auto,
    /// Base solutions, solved and cached where missing; not the SPP light.
    Always,
    /// Solved for the scene's sun per model.
    Never,
}

/// The light as asked for, before it is checked.
#[derive(Debug, Clone, PartialEq)]
pub struct LightSettings {
    /// `physical`, `paper` or `spp` (the paper's shading with the plane-parallel light);
    /// `None`: the physical light.
    pub light: Option<String>,
    pub basis: BasisChoice,
    /// How base solutions combine for the sun.
    pub sun: SunWeights,
    /// Ambient light from the ambient base solution, as a fraction of unobstructed sunlight.
    pub ambient: f64,
    /// Sites of the coarse global grid (relighting) or forest grid (physical light) along
    /// the forest's longest edge; `None`: without it.
    pub global_grid: Option<usize>,
    /// Compression of cached base solutions (`colour:T`, `haar:T`, `pca:K`, `pcahaar:K:T`).
    pub codec: String,
    /// Stored values of compressed base solutions.
    pub precision: Precision,
}

/// [`LightSettings`] checked: the light model, and where they apply the relighting plan and
/// the physical light's forest grid.
#[derive(Debug, Clone, PartialEq)]
pub struct LightChoice {
    /// `physical`, `paper` or `spp`.
    pub name: &'static str,
    /// The light model the LB and the shading use (the SPP light shades as the paper's).
    pub light: Light,
    pub relight: Option<RelightPlan>,
    pub forest: Option<GlobalGridOptions>,
}

/// The light model's name for a command that relights from base solutions: the physical
/// light by default, or the paper light; the SPP light has none (an error, not another
/// light's bases shaded as it).
pub fn relight_light(light: Option<&str>) -> Result<&'static str, OptionError> {
    match light {
        None | Some("physical") => Ok("physical"),
        Some("paper") => Ok("paper"),
        Some(l) => Err(refuse(format!(
            "--light {l}: this command relights from base solutions, and the {l} light has \
             none (docs/relight.md): use the physical light (the default) or --light paper"
        ))),
    }
}

impl LightSettings {
    /// The light model's name: by default physical ([`relight_light`] for a command that
    /// relights).
    pub fn name(&self, relights: bool) -> Result<&'static str, OptionError> {
        match (self.light.as_deref(), relights) {
            (l, true) => relight_light(l),
            (None | Some("physical"), false) => Ok("physical"),
            (Some("paper"), false) => Ok("paper"),
            (Some("spp"), false) => Ok("spp"),
            (Some(_), false) => Err(refuse("--light".into())),
        }
    }

    /// The relighting plan under light `light` (`None`: per-sun LB light). `force`: base
    /// solutions whatever `basis` says (`Auto` then solves missing ones); `keep_raw`: keep
    /// the uncompressed bases too. The physical and the paper light have base solutions
    /// (`Always` with the SPP light is an error); `Auto` takes them when every model's are
    /// cached, else solves for the sun (docs/relight.md).
    pub fn plan(
        &self,
        force: bool,
        keep_raw: bool,
        light: &str,
    ) -> Result<Option<RelightPlan>, OptionError> {
        let paper = light == "paper";
        let basis = match (self.basis, force) {
            (BasisChoice::Never, true) => {
                return Err(refuse(
                    "--basis never: this command relights from base solutions".into(),
                ))
            }
            (BasisChoice::Never, false) => return Ok(None),
            (BasisChoice::Always, false) if light == "spp" => {
                return Err(refuse(
                    "--basis always: the SPP light has no base solutions (docs/relight.md); \
                     use the physical light (the default) or --light paper"
                        .into(),
                ))
            }
            (BasisChoice::Auto, false) if light == "spp" => return Ok(None),
            (BasisChoice::Auto, false) => BasisUse::IfCached,
            _ => BasisUse::Always,
        };
        if !(self.ambient.is_finite() && self.ambient >= 0.0) {
            return Err(refuse(format!(
                "--ambient {}: must be a finite number ≥ 0",
                self.ambient
            )));
        }
        let global = self.global_grid.map(|sites| GlobalGridOptions { sites });
        if let Some(g) = &global {
            g.validate()
                .map_err(|e| refuse(format!("--global-grid: {e}")))?;
        }
        // The paper light's bases are one set; the physical light's two (sun parts, diffuse
        // parts), or none.
        let (target, physical) = if paper {
            let codec = Codec::parse(&self.codec).map_err(|e| {
                refuse(format!(
                    "--codec: {e} (the paper light's bases take one codec, not none)"
                ))
            })?;
            let target = CompressTarget {
                precision: self.precision,
                ..CompressTarget::new(codec)
            };
            target
                .validate()
                .map_err(|e| refuse(format!("--codec/--basis-precision: {e}")))?;
            (target, None)
        } else {
            let physical = PhysicalTarget::parse(&self.codec, self.precision)
                .map_err(|e| refuse(format!("--codec/--basis-precision: {e}")))?;
            (CompressTarget::recommended(), physical)
        };
        Ok(Some(RelightPlan {
            basis,
            sun: self.sun,
            ambient: self.ambient,
            global,
            target,
            physical,
            keep_raw,
        }))
    }

    /// The physical light's coarse forest grid; `None` without one or for other lights.
    pub fn forest_grid(&self, light: Light) -> Result<Option<GlobalGridOptions>, OptionError> {
        let Some(sites) = self.global_grid.filter(|_| light == Light::Physical) else {
            return Ok(None);
        };
        let g = GlobalGridOptions { sites };
        g.validate()
            .map_err(|e| refuse(format!("--global-grid: {e}")))?;
        Ok(Some(g))
    }

    /// The light checked for a command: `relights` forces base solutions (a command that
    /// relights), `keep_raw` keeps the uncompressed ones, and without `need_lb` (no LB work)
    /// there is no plan, though `--basis always` with the SPP light is still refused, not
    /// ignored.
    pub fn choose(
        &self,
        relights: bool,
        keep_raw: bool,
        need_lb: bool,
    ) -> Result<LightChoice, OptionError> {
        let name = self.name(relights)?;
        // The SPP light replaces the paper's LB grids under the paper's shading.
        let light = match name {
            "spp" => Light::Paper,
            l => Light::parse(l).ok_or_else(|| refuse("--light".into()))?,
        };
        let relight = if need_lb || self.basis == BasisChoice::Always {
            self.plan(relights, keep_raw, name)?.filter(|_| need_lb)
        } else {
            None
        };
        Ok(LightChoice {
            name,
            light,
            relight,
            forest: self.forest_grid(light)?,
        })
    }
}

/// A warning line before a coarse grid (`plan`'s relighting grid, or the physical light's
/// forest grid `forest`) whose solves cost far more than the default's, if `scene` will solve
/// one; `None` otherwise.
pub fn costly_grid_warning(
    scene: &Scene,
    plan: Option<&RelightPlan>,
    forest: Option<&GlobalGridOptions>,
    light: Light,
) -> Result<Option<String>, OptionError> {
    let physical_bases = plan.is_some() && light == Light::Physical;
    let (grid, solves) = match (plan.and_then(|p| p.global.as_ref()), forest) {
        // The physical light's forest grid parts: 25 sun directions, a sky and a ground.
        (_, Some(g)) if physical_bases && uses_forest(scene, light, Some(g)) => {
            (g, 3 * (sylva_light::relight::physical::SUN_PARTS + 2))
        }
        (_, None) if physical_bases => return Ok(None),
        (Some(g), _) => (g, sylva_lb::relight::BASES - 1),
        (None, Some(g)) if uses_forest(scene, light, Some(g)) => (g, 3),
        _ => return Ok(None),
    };
    let b = scene.instance_bounds();
    if b.is_empty() {
        return Ok(None);
    }
    grid.cost_warning(b.max - b.min, solves)
        .map_err(|e| refuse(format!("--global-grid: {e}")))
        .map(|w| w.map(|w| format!("warning: {w}, where it is not cached")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> LightSettings {
        LightSettings {
            light: None,
            basis: BasisChoice::Auto,
            sun: SunWeights::ThreeBasis,
            ambient: 0.0,
            global_grid: Some(64),
            codec: "colour:0.004".into(),
            precision: Precision::Packed,
        }
    }

    /// `--basis` against the light and the command: auto takes cached bases of the physical
    /// and the paper light (the SPP light has none), a command that relights always has a
    /// plan, and the lights without base solutions are refused where bases are asked for.
    #[test]
    fn basis_choice_against_light_and_command() {
        let s = settings();
        let auto = s.choose(false, false, true).unwrap();
        assert_eq!((auto.name, auto.light), ("physical", Light::Physical));
        assert_eq!(auto.relight.unwrap().basis, BasisUse::IfCached);
        assert_eq!(auto.forest, Some(GlobalGridOptions { sites: 64 }));
        let paper = LightSettings {
            light: Some("paper".into()),
            ..s.clone()
        };
        let plan = paper.choose(false, false, true).unwrap().relight.unwrap();
        assert_eq!(plan.basis, BasisUse::IfCached);
        assert!(paper.choose(false, false, true).unwrap().forest.is_none());
        let forced = s.choose(true, true, true).unwrap().relight.unwrap();
        assert_eq!((forced.basis, forced.keep_raw), (BasisUse::Always, true));
        let spp = LightSettings {
            light: Some("spp".into()),
            basis: BasisChoice::Always,
            ..s.clone()
        };
        assert!(spp
            .choose(false, false, false)
            .unwrap_err()
            .0
            .starts_with("--basis always"));
        assert!(spp
            .choose(true, false, true)
            .unwrap_err()
            .0
            .starts_with("--light spp"));
        let never = LightSettings {
            basis: BasisChoice::Never,
            ..s.clone()
        };
        assert!(never.choose(false, false, true).unwrap().relight.is_none());
        assert!(never.plan(true, false, "physical").is_err());
    }

    /// Each bad value is refused with its flag named.
    #[test]
    fn bad_values_name_their_flag() {
        let s = settings();
        let bad = |s: LightSettings| s.plan(true, false, "paper").unwrap_err().0;
        assert!(bad(LightSettings {
            ambient: -1.0,
            ..s.clone()
        })
        .starts_with("--ambient -1"));
        assert!(bad(LightSettings {
            global_grid: Some(8),
            ..s.clone()
        })
        .starts_with("--global-grid: "));
        assert!(bad(LightSettings {
            codec: "bad".into(),
            ..s.clone()
        })
        .starts_with("--codec: "));
        let off = LightSettings {
            global_grid: None,
            ..s
        };
        assert!(off
            .plan(true, false, "paper")
            .unwrap()
            .unwrap()
            .global
            .is_none());
        assert!(off.forest_grid(Light::Physical).unwrap().is_none());
    }
}
