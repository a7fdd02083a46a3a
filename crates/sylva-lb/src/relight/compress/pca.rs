//! Principal components across the channels of a set of parts (three colours each): the 57
//! of a paper basis set, or the physical light's parts.
//!
//! The 19 bases × 3 colours at a site are strongly correlated (neighbouring directions light a
//! site alike, and the three colours differ only a little in σ_a and g). Each channel is first
//! divided by its scale (a basis's free-space value: 18 for `B_0`, 1 for the others), so that
//! every channel counts as it does in a normalised combination; the mean and covariance are
//! taken over the sites of the region (where light matters) and the `k` leading eigenvectors
//! kept. Sums run in fixed chunks combined in order, so the fit does not depend on the thread
//! count; each component's sign is fixed (its largest entry positive).

use nalgebra::{DMatrix, SymmetricEigen};
use rayon::prelude::*;

use crate::grid::Dims;
use crate::relight::region::Region;
use crate::relight::RelightError;

/// Sites per parallel work item.
const CHUNK: usize = 4096;

/// A fitted PCA: `channel ≈ mean + Σ_f components[ch][f] · field_f`, in channel units.
#[derive(Debug, Clone, PartialEq)]
pub struct Pca {
    /// Per channel.
    pub mean: Vec<f32>,
    /// `channels × rank`, row-major (`[channel][field]`).
    pub components: Vec<f32>,
    pub rank: usize,
    /// Variance of each kept component, and the total over all channels (normalised units).
    pub variances: Vec<f64>,
    pub total_variance: f64,
    /// The coefficient fields, site-major: field f of site s at `s * rank + f`.
    pub coefficients: Vec<f32>,
}

/// Which components are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Structure {
    /// The `rank` leading components of all channels.
    Global { rank: usize },
    /// Per part (base solution), the 3 components of its three colours (as many as channels,
    /// block-diagonal): decorrelates the colours, whose minor components are small and
    /// compress well.
    PerBasis,
}

/// The `rank` leading unit eigenvectors of the `size`² block of `cov` at (`at`, `at`),
/// embedded in channel space, with their variances; each with its largest entry positive.
fn leading(cov: &DMatrix<f64>, at: usize, size: usize, rank: usize) -> (Vec<Vec<f64>>, Vec<f64>) {
    let channels = cov.nrows();
    let eigen = SymmetricEigen::new(cov.view((at, at), (size, size)).clone_owned());
    let mut order: Vec<usize> = (0..size).collect();
    order.sort_by(|&a, &b| {
        eigen.eigenvalues[b]
            .total_cmp(&eigen.eigenvalues[a])
            .then(a.cmp(&b))
    });
    let unit = order[..rank]
        .iter()
        .map(|&i| {
            let col = eigen.eigenvectors.column(i);
            let big = (0..size)
                .max_by(|&a, &b| col[a].abs().total_cmp(&col[b].abs()).then(b.cmp(&a)))
                .expect("a non-empty block");
            let sign = if col[big] < 0.0 { -1.0 } else { 1.0 };
            let mut u = vec![0.0; channels];
            for k in 0..size {
                u[at + k] = sign * col[k];
            }
            u
        })
        .collect();
    let variances = order[..rank]
        .iter()
        .map(|&i| eigen.eigenvalues[i].max(0.0))
        .collect();
    (unit, variances)
}

/// Fits components of the `channels` channels `value(channel, site)` of a `dims` grid, each
/// in units of its `scales` entry, over `region`, and projects every site onto them.
pub fn fit(
    dims: Dims,
    channels: usize,
    value: &(dyn Fn(usize, usize) -> f32 + Sync),
    scales: &[f64],
    region: &Region,
    structure: Structure,
) -> Result<Pca, RelightError> {
    let sites = region.sites();
    if sites.is_empty() {
        return Err(RelightError::Target(
            "the region holds no sites: nothing to fit components to".into(),
        ));
    }
    assert_eq!(scales.len(), channels, "one scale per channel");
    // The factor that normalises each channel.
    let norm: Vec<f64> = scales.iter().map(|s| 1.0 / s).collect();
    let scale = |c: usize| norm[c];
    let value = |c: usize, s: usize| value(c, s) as f64 * scale(c);
    // Mean.
    let partial: Vec<Vec<f64>> = sites
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut acc = vec![0.0f64; channels];
            for &s in chunk {
                for (c, a) in acc.iter_mut().enumerate() {
                    *a += value(c, s);
                }
            }
            acc
        })
        .collect();
    let mut mean = vec![0.0f64; channels];
    for p in &partial {
        for (m, v) in mean.iter_mut().zip(p) {
            *m += v;
        }
    }
    mean.iter_mut().for_each(|m| *m /= sites.len() as f64);
    // Covariance (upper triangle).
    let partial: Vec<Vec<f64>> = sites
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut acc = vec![0.0f64; channels * channels];
            let mut x = vec![0.0f64; channels];
            for &s in chunk {
                for (c, v) in x.iter_mut().enumerate() {
                    *v = value(c, s) - mean[c];
                }
                for a in 0..channels {
                    let row = &mut acc[a * channels..(a + 1) * channels];
                    for b in a..channels {
                        row[b] += x[a] * x[b];
                    }
                }
            }
            acc
        })
        .collect();
    let mut cov = DMatrix::<f64>::zeros(channels, channels);
    for p in &partial {
        for a in 0..channels {
            for b in a..channels {
                cov[(a, b)] += p[a * channels + b];
            }
        }
    }
    for a in 0..channels {
        for b in a..channels {
            let v = cov[(a, b)] / sites.len() as f64;
            cov[(a, b)] = v;
            cov[(b, a)] = v;
        }
    }
    let total_variance: f64 = (0..channels).map(|c| cov[(c, c)]).sum();
    let (unit, variances) = match structure {
        Structure::Global { rank } => leading(&cov, 0, channels, rank),
        Structure::PerBasis => {
            let (mut unit, mut variances) = (Vec::new(), Vec::new());
            for j in 0..channels / 3 {
                let (u, v) = leading(&cov, 3 * j, 3, 3);
                unit.extend(u);
                variances.extend(v);
            }
            (unit, variances)
        }
    };
    let rank = unit.len();
    // Project every site: field_f = Σ_ch u_f[ch] (x_ch - mean_ch).
    let n = dims.sites();
    sylva_core::check_memory(
        &format!("{rank} component fields on a {} grid", dims),
        (rank * n * 4) as u64,
    )?;
    let mut by_site = vec![0.0f32; n * rank];
    by_site
        .par_chunks_mut(CHUNK * rank)
        .enumerate()
        .for_each(|(k, out)| {
            let base = k * CHUNK;
            let mut x = vec![0.0f64; channels];
            for (i, o) in out.chunks_mut(rank).enumerate() {
                let s = base + i;
                for (c, v) in x.iter_mut().enumerate() {
                    *v = value(c, s) - mean[c];
                }
                for (f, u) in unit.iter().enumerate() {
                    o[f] = u.iter().zip(&x).map(|(a, b)| a * b).sum::<f64>() as f32;
                }
            }
        });
    // Back to channel units.
    let mut components = vec![0.0f32; channels * rank];
    for c in 0..channels {
        for f in 0..rank {
            components[c * rank + f] = (unit[f][c] / scale(c)) as f32;
        }
    }
    Ok(Pca {
        mean: (0..channels).map(|c| (mean[c] / scale(c)) as f32).collect(),
        components,
        rank,
        variances,
        total_variance,
        coefficients: by_site,
    })
}
