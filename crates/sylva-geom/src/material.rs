//! Surface materials: leaf and wood are kept apart so the LB voxelizer can mark green (leaf)
//! and brown (wood) sites, and the renderer can alpha-test leaves.

use crate::texture::Texture;
use std::sync::Arc;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MaterialKind {
    Leaf,
    Wood,
}

#[derive(Debug, Clone)]
pub struct Material {
    pub name: String,
    pub kind: MaterialKind,
    /// Representative linear RGB in [0, 1] (the texture's mean opaque colour when there is
    /// one): what LB voxels and untextured previews use. A renderer with the texture uses the
    /// texel colour instead.
    pub base_color: [f32; 3],
    /// Leaf textures carry the leaf shape in alpha; bark textures are opaque and repeat.
    pub texture: Option<Arc<Texture>>,
    /// Leaves are single quads seen from both sides; bark tubes are closed.
    pub two_sided: bool,
}

impl Material {
    pub fn is_leaf(&self) -> bool {
        self.kind == MaterialKind::Leaf
    }
}
