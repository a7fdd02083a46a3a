//! Lattice-Boltzmann photon transport (paper 002 §3).
