#!/bin/sh
# The cloud LB benchmark of docs/PERFORMANCE.md: three rounds, alternated, of the dense 128³
# baseline, the built-in cloud with the papers' step count and with a convergence stop; one
# JSON line each. Run from the repository root after `cargo build --release`.
set -e
sylva=${SYLVA:-./target/release/sylva}
for round in 1 2 3; do
  "$sylva" bench lb --repeats 1 --json
  "$sylva" bench lb --medium cloud --repeats 1 --json
  "$sylva" bench lb --medium cloud --tolerance 1e-4 --repeats 1 --json
done
