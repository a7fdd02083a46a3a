//! Indexed triangle meshes and models (mesh + materials + bounds).

use crate::material::Material;
use glam::Vec3;
use sylva_core::Fnv64;

/// Axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (min = +inf, max = -inf): the identity of [`Aabb::union`].
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    pub fn size(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            self.max - self.min
        }
    }

    pub fn corners(&self) -> [Vec3; 8] {
        let (a, b) = (self.min, self.max);
        [
            Vec3::new(a.x, a.y, a.z),
            Vec3::new(b.x, a.y, a.z),
            Vec3::new(a.x, b.y, a.z),
            Vec3::new(b.x, b.y, a.z),
            Vec3::new(a.x, a.y, b.z),
            Vec3::new(b.x, a.y, b.z),
            Vec3::new(a.x, b.y, b.z),
            Vec3::new(b.x, b.y, b.z),
        ]
    }
}

/// Indexed triangles with per-vertex position, normal and texture coordinates, and a material
/// index per triangle. Kept compact (f32, u32, u8) because forests instance millions of them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
    /// Index into the owning model's `materials`, one per triangle.
    pub material_ids: Vec<u8>,
}

impl Mesh {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// Adds a vertex and returns its index.
    pub fn push_vertex(&mut self, p: Vec3, n: Vec3, uv: [f32; 2]) -> u32 {
        let i = self.positions.len() as u32;
        self.positions.push(p.to_array());
        self.normals.push(n.to_array());
        self.uvs.push(uv);
        i
    }

    pub fn push_triangle(&mut self, a: u32, b: u32, c: u32, material: u8) {
        self.indices.push([a, b, c]);
        self.material_ids.push(material);
    }

    /// Appends `other`, shifting its indices.
    pub fn append(&mut self, other: &Mesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.normals.extend_from_slice(&other.normals);
        self.uvs.extend_from_slice(&other.uvs);
        self.indices.extend(
            other
                .indices
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
        self.material_ids.extend_from_slice(&other.material_ids);
    }

    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for p in &self.positions {
            b.grow(Vec3::from_array(*p));
        }
        b
    }

    /// Bytes held by the mesh's arrays.
    pub fn memory_bytes(&self) -> u64 {
        (self.positions.capacity() * 12
            + self.normals.capacity() * 12
            + self.uvs.capacity() * 8
            + self.indices.capacity() * 12
            + self.material_ids.capacity()) as u64
    }

    /// Triangles using material `id`.
    pub fn triangles_with_material(&self, id: u8) -> usize {
        self.material_ids.iter().filter(|&&m| m == id).count()
    }

    /// Stable hash ([`Fnv64`]) over every array (bit patterns of the floats): equal hashes
    /// mean identical geometry. Checks that generation is deterministic; part of LB cache keys.
    pub fn geometry_hash(&self) -> u64 {
        let mut h = Fnv64::new();
        for p in self.positions.iter().chain(&self.normals) {
            p.iter().for_each(|&v| h.f32(v));
        }
        for uv in &self.uvs {
            uv.iter().for_each(|&v| h.f32(v));
        }
        for t in &self.indices {
            t.iter().for_each(|&i| h.u32(i));
        }
        for &m in &self.material_ids {
            h.u32(m as u32);
        }
        h.finish()
    }

    /// Checks the invariants the renderer relies on; returns a description of the first defect.
    pub fn validate(&self, material_count: usize) -> Result<(), String> {
        let n = self.positions.len();
        if self.normals.len() != n || self.uvs.len() != n {
            return Err(format!(
                "{} positions but {} normals and {} uvs",
                n,
                self.normals.len(),
                self.uvs.len()
            ));
        }
        if self.material_ids.len() != self.indices.len() {
            return Err("material_ids and indices differ in length".into());
        }
        if let Some(t) = self
            .indices
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= n))
        {
            return Err(format!("triangle {t:?} indexes past {n} vertices"));
        }
        if let Some(m) = self
            .material_ids
            .iter()
            .find(|&&m| m as usize >= material_count)
        {
            return Err(format!(
                "material id {m} but only {material_count} materials"
            ));
        }
        if self
            .positions
            .iter()
            .chain(&self.normals)
            .any(|p| p.iter().any(|v| !v.is_finite()))
        {
            return Err("non-finite position or normal".into());
        }
        Ok(())
    }
}

/// A plant (or any object): one mesh, its materials (indexed by the mesh's material ids) and
/// its bounds in model space (ground contact at y = 0 for trees).
#[derive(Debug, Clone)]
pub struct Model {
    pub name: String,
    pub mesh: Mesh,
    pub materials: Vec<Material>,
    pub bounds: Aabb,
}

impl Model {
    pub fn new(name: impl Into<String>, mesh: Mesh, materials: Vec<Material>) -> Model {
        let bounds = mesh.bounds();
        Model {
            name: name.into(),
            mesh,
            materials,
            bounds,
        }
    }

    pub fn triangle_count(&self) -> usize {
        self.mesh.triangle_count()
    }

    /// Mesh arrays plus texture pixels.
    pub fn memory_bytes(&self) -> u64 {
        self.mesh.memory_bytes()
            + self
                .materials
                .iter()
                .filter_map(|m| m.texture.as_ref())
                .map(|t| t.memory_bytes())
                .sum::<u64>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> Mesh {
        let mut m = Mesh::default();
        let a = m.push_vertex(Vec3::ZERO, Vec3::Y, [0.0, 0.0]);
        let b = m.push_vertex(Vec3::X, Vec3::Y, [1.0, 0.0]);
        let c = m.push_vertex(Vec3::new(1.0, 0.0, 1.0), Vec3::Y, [1.0, 1.0]);
        let d = m.push_vertex(Vec3::Z, Vec3::Y, [0.0, 1.0]);
        m.push_triangle(a, b, c, 0);
        m.push_triangle(a, c, d, 1);
        m
    }

    #[test]
    fn append_shifts_indices_and_bounds_cover() {
        let mut m = quad();
        let mut other = quad();
        for p in &mut other.positions {
            p[1] += 2.0;
        }
        m.append(&other);
        assert_eq!(m.triangle_count(), 4);
        assert_eq!(m.indices[2], [4, 5, 6]);
        assert_eq!(m.bounds().max, Vec3::new(1.0, 2.0, 1.0));
        assert_eq!(m.triangles_with_material(1), 2);
        assert!(m.validate(2).is_ok());
        assert!(m.validate(1).is_err());
    }

    #[test]
    fn hash_sees_any_change() {
        let m = quad();
        let mut n = quad();
        assert_eq!(m.geometry_hash(), n.geometry_hash());
        n.positions[2][0] = 1.0001;
        assert_ne!(m.geometry_hash(), n.geometry_hash());
    }

    #[test]
    fn hash_is_stable_across_releases() {
        // LB cache entries are keyed by it: a change here orphans every cache entry.
        assert_eq!(quad().geometry_hash(), 14_790_618_558_702_144_374);
    }
}
