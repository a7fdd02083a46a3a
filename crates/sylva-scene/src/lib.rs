//! Tree models, the species generator and forest scenes: what sylva lights and renders.
