//! What `sylva species list` and `sylva species show` report: each built-in species' triangle
//! count and size ([`SpeciesTable`]), one species' parameters and look ([`SpeciesSheet`]), as
//! text (`Display`) or JSON (`Serialize`); and a species named on a command line, built-in or
//! an Arbaro file ([`resolve`]).

use std::fmt;
use std::path::Path;

use serde::{Serialize, Serializer};
use sylva_core::thousands;

use crate::arbaro::{self, ArbaroError};
use crate::species::BUILTIN_NAMES;
use crate::textures::{BarkPattern, LeafOutline};
use crate::weber_penn::{GenerateError, LEAF};
use crate::Species;

#[derive(Debug, thiserror::Error)]
pub enum SheetError {
    #[error(
        "no built-in species '{name}' and no such Arbaro file (built-in species: {})",
        BUILTIN_NAMES.join(", ")
    )]
    NotFound { name: String },
    #[error(transparent)]
    Arbaro(#[from] ArbaroError),
    #[error("generating {name}")]
    Generate {
        name: String,
        #[source]
        source: GenerateError,
    },
}

/// A built-in species by name, or else the Arbaro species file at that path.
pub fn resolve(name: &str) -> Result<Species, SheetError> {
    if let Some(s) = Species::builtin(name) {
        return Ok(s);
    }
    let path = Path::new(name);
    if path.exists() {
        let a = arbaro::load_file(path)?;
        return Ok(Species::from_params(
            &a.name,
            a.params,
            a.seed.unwrap_or(0),
            path.display().to_string(),
        ));
    }
    Err(SheetError::NotFound {
        name: name.to_string(),
    })
}

fn mesh_of(s: &Species) -> Result<sylva_geom::Mesh, SheetError> {
    s.generate_mesh().map_err(|source| SheetError::Generate {
        name: s.name.clone(),
        source,
    })
}

/// One species of [`SpeciesTable`].
#[derive(Debug, Clone, Serialize)]
pub struct SpeciesRow {
    pub name: String,
    pub triangles: usize,
    /// Triangles per instance reported by the source, where it reports one.
    pub reference_triangles: Option<usize>,
    /// The tree's extent along x, y and z in metres.
    pub size_m: [f32; 3],
    pub source: String,
}

/// Every built-in species, generated: `sylva species list`.
#[derive(Debug, Clone, Serialize)]
#[serde(transparent)]
pub struct SpeciesTable(pub Vec<SpeciesRow>);

impl SpeciesTable {
    pub fn builtin() -> Result<SpeciesTable, SheetError> {
        let mut rows = Vec::new();
        for s in Species::all_builtin() {
            let mesh = mesh_of(&s)?;
            rows.push(SpeciesRow {
                triangles: mesh.triangle_count(),
                reference_triangles: s.reference_triangles,
                size_m: mesh.bounds().size().to_array(),
                name: s.name,
                source: s.source,
            });
        }
        Ok(SpeciesTable(rows))
    }
}

impl fmt::Display for SpeciesTable {
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            o,
            "{:<18} {:>11} {:>13} {:>8}  source",
            "species", "triangles", "paper", "height"
        )?;
        for s in &self.0 {
            let paper = s
                .reference_triangles
                .map(|r| thousands(r as u64))
                .unwrap_or_else(|| "-".into());
            writeln!(
                o,
                "{:<18} {:>11} {:>13} {:>7.1}m  {}",
                s.name,
                thousands(s.triangles as u64),
                paper,
                s.size_m[1],
                s.source
            )?;
        }
        Ok(())
    }
}

/// One species, generated: `sylva species show`.
#[derive(Debug, Clone, Serialize)]
pub struct SpeciesSheet {
    pub name: String,
    pub source: String,
    pub seed: u64,
    pub triangles: usize,
    pub leaf_triangles: usize,
    pub wood_triangles: usize,
    pub reference_triangles: Option<usize>,
    pub vertices: usize,
    pub bounds_min: [f32; 3],
    pub bounds_max: [f32; 3],
    /// The extent along x, y and z (zero for an empty mesh); JSON gives the bounds.
    #[serde(skip)]
    pub size: [f32; 3],
    pub leaf_outline: LeafOutline,
    pub leaf_color_srgb: [u8; 3],
    /// The leaf's measured mean reflectance and transmittance (linear R, G, B) and where
    /// they come from.
    pub leaf_reflectance: [f32; 3],
    pub leaf_transmittance: [f32; 3],
    pub leaf_source: String,
    pub bark_pattern: BarkPattern,
    pub bark_color_srgb: [u8; 3],
    /// Arbaro's parameter names and values, in [`crate::weber_penn::Params::entries`]' order.
    #[serde(serialize_with = "as_map")]
    pub params: Vec<(String, f64)>,
}

fn as_map<S: Serializer>(entries: &[(String, f64)], s: S) -> Result<S::Ok, S::Error> {
    s.collect_map(entries.iter().map(|(k, v)| (k, v)))
}

impl SpeciesSheet {
    pub fn of(s: &Species) -> Result<SpeciesSheet, SheetError> {
        let mesh = mesh_of(s)?;
        let leaf = mesh.triangles_with_material(LEAF);
        let b = mesh.bounds();
        Ok(SpeciesSheet {
            name: s.name.clone(),
            source: s.source.clone(),
            seed: s.seed,
            triangles: mesh.triangle_count(),
            leaf_triangles: leaf,
            wood_triangles: mesh.triangle_count() - leaf,
            reference_triangles: s.reference_triangles,
            vertices: mesh.vertex_count(),
            bounds_min: b.min.to_array(),
            bounds_max: b.max.to_array(),
            size: b.size().to_array(),
            leaf_outline: s.leaf_outline,
            leaf_color_srgb: s.leaf_color,
            leaf_reflectance: s.leaf.reflectance,
            leaf_transmittance: s.leaf.transmittance,
            leaf_source: s.leaf_source.clone(),
            bark_pattern: s.bark_pattern,
            bark_color_srgb: s.bark_color,
            params: s.params.entries(),
        })
    }
}

impl fmt::Display for SpeciesSheet {
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(o, "species {} ({})", self.name, self.source)?;
        writeln!(
            o,
            "  triangles   {} ({} leaf, {} wood){}",
            thousands(self.triangles as u64),
            thousands(self.leaf_triangles as u64),
            thousands(self.wood_triangles as u64),
            self.reference_triangles
                .map(|r| format!("; paper: {}", thousands(r as u64)))
                .unwrap_or_default()
        )?;
        let size = self.size;
        writeln!(
            o,
            "  size        {:.1} × {:.1} × {:.1} m (x × y × z)",
            size[0], size[1], size[2]
        )?;
        writeln!(
            o,
            "  leaves      {:?}, sRGB {:?}; bark {:?}, sRGB {:?}; seed {}",
            self.leaf_outline,
            self.leaf_color_srgb,
            self.bark_pattern,
            self.bark_color_srgb,
            self.seed
        )?;
        let (r, t) = (self.leaf_reflectance, self.leaf_transmittance);
        writeln!(
            o,
            "  leaf R, T   reflectance {:.3}, {:.3}, {:.3}; transmittance {:.3}, {:.3}, {:.3} \
             (measured, linear R, G, B; the texture shapes only the pattern)",
            r[0], r[1], r[2], t[0], t[1], t[2]
        )?;
        writeln!(o, "  leaf source {}", self.leaf_source)?;
        writeln!(
            o,
            "  bark R      its texture's colour (no measured bark in the papers yet)"
        )?;
        writeln!(o, "  parameters (Arbaro names):")?;
        for (k, v) in &self.params {
            writeln!(o, "    {k:<16} {v}")?;
        }
        Ok(())
    }
}
