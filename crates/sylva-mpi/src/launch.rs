//! Whether this process is one of several started by `mpirun`/`mpiexec`, read from the
//! environment the launcher sets (before, and without, initialising MPI): so that a build
//! without MPI refuses instead of having every process render the whole image.

/// Variables holding the number of processes the launcher started: Open MPI's, then the
/// PMI ones of MPICH's Hydra and Slurm.
const SIZE_VARS: [&str; 3] = ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE"];
/// Variables holding the number of processes started on this machine.
const LOCAL_SIZE_VARS: [&str; 2] = ["OMPI_COMM_WORLD_LOCAL_SIZE", "MPI_LOCALNRANKS"];

fn first_count(vars: &[&str], get: &dyn Fn(&str) -> Option<String>) -> Option<usize> {
    vars.iter()
        .find_map(|v| get(v))
        .and_then(|s| s.trim().parse::<usize>().ok())
}

/// The number of processes of the launch this one belongs to, if a launcher started it.
pub fn launched_size() -> Option<usize> {
    first_count(&SIZE_VARS, &|v| std::env::var(v).ok())
}

/// How many of them run on this machine (for sharing its cores), if the launcher says.
pub fn local_size() -> Option<usize> {
    first_count(&LOCAL_SIZE_VARS, &|v| std::env::var(v).ok())
}

/// The worker threads of each process of a launch of several: the `cores` of this machine
/// shared among its `local` processes (at least one each, at most
/// [`sylva_core::limits::THREADS`]' end); `None` when not one of several or the launcher does
/// not say how many share the machine.
pub fn shared_threads(
    launched: Option<usize>,
    local: Option<usize>,
    cores: usize,
) -> Option<usize> {
    launched.filter(|&n| n > 1)?;
    let local = local?;
    Some((cores / local.max(1)).clamp(1, *sylva_core::limits::THREADS.end()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Several processes on one machine share its cores; one process, or an unknown share,
    /// leaves the thread count alone.
    #[test]
    fn ranks_on_one_machine_share_its_cores() {
        assert_eq!(shared_threads(Some(4), Some(2), 16), Some(8));
        assert_eq!(shared_threads(Some(4), Some(4), 2), Some(1));
        assert_eq!(shared_threads(Some(2), Some(1), 1024), Some(256));
        assert_eq!(shared_threads(Some(1), Some(1), 16), None);
        assert_eq!(shared_threads(None, Some(2), 16), None);
        assert_eq!(shared_threads(Some(4), None, 16), None);
    }

    #[test]
    fn counts_come_from_the_first_variable_set() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |v: &str| {
                pairs
                    .iter()
                    .find(|(k, _)| *k == v)
                    .map(|(_, x)| x.to_string())
            }
        };
        assert_eq!(first_count(&SIZE_VARS, &env(&[])), None);
        assert_eq!(
            first_count(&SIZE_VARS, &env(&[("OMPI_COMM_WORLD_SIZE", "3")])),
            Some(3)
        );
        assert_eq!(
            first_count(&SIZE_VARS, &env(&[("PMI_SIZE", " 2 ")])),
            Some(2)
        );
        assert_eq!(first_count(&SIZE_VARS, &env(&[("PMI_SIZE", "x")])), None);
    }
}
