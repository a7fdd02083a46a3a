//! Plane-parallel scattering in homogeneous slabs: the full discrete-ordinates model, the simplified (SPP) model and a Monte Carlo reference (paper 003).
