//! Reading a checkpoint's attributes and datasets, each failure an error that names the
//! file and the item: what the reader and the row checks share.

use std::path::Path;

pub(super) fn attr_u64(f: &hdf5::File, p: &Path, name: &str) -> Result<u64, String> {
    f.attr(name)
        .and_then(|a| a.read_scalar::<u64>())
        .map_err(|e| {
            format!(
                "{}: damaged checkpoint: attribute `{name}`: {e}",
                p.display()
            )
        })
}

pub(super) fn attr_f64(f: &hdf5::File, p: &Path, name: &str) -> Result<f64, String> {
    f.attr(name)
        .and_then(|a| a.read_scalar::<f64>())
        .map_err(|e| {
            format!(
                "{}: damaged checkpoint: attribute `{name}`: {e}",
                p.display()
            )
        })
}

pub(super) fn attr_vec<T: hdf5::H5Type>(
    f: &hdf5::File,
    p: &Path,
    name: &str,
    len: usize,
) -> Result<Vec<T>, String> {
    let v: Vec<T> = f.attr(name).and_then(|a| a.read_raw::<T>()).map_err(|e| {
        format!(
            "{}: damaged checkpoint: attribute `{name}`: {e}",
            p.display()
        )
    })?;
    if v.len() != len {
        return Err(format!(
            "{}: damaged checkpoint: attribute `{name}` has {} values, expected {len}",
            p.display(),
            v.len()
        ));
    }
    Ok(v)
}

pub(super) fn dataset<T: hdf5::H5Type>(
    f: &hdf5::File,
    p: &Path,
    name: &str,
    len: usize,
) -> Result<Vec<T>, String> {
    let v: Vec<T> = f
        .dataset(name)
        .and_then(|d| d.read_raw::<T>())
        .map_err(|e| format!("{}: damaged checkpoint: dataset `{name}`: {e}", p.display()))?;
    if v.len() != len {
        return Err(format!(
            "{}: damaged checkpoint: dataset `{name}` has {} values, expected {len}",
            p.display(),
            v.len()
        ));
    }
    Ok(v)
}

pub(super) fn dataset_any<T: hdf5::H5Type>(
    f: &hdf5::File,
    p: &Path,
    name: &str,
) -> Result<Vec<T>, String> {
    f.dataset(name)
        .and_then(|d| d.read_raw::<T>())
        .map_err(|e| format!("{}: damaged checkpoint: dataset `{name}`: {e}", p.display()))
}

/// From here on not every integer is exact in f64 (the particle record, the history):
/// no step count or particle id reaches it.
pub(super) const F64_INTEGERS: u64 = 1 << 53;

/// `values` of `what` (an attribute or dataset) are finite and, if `nonneg`, >= 0.
pub(super) fn finite(path: &Path, what: &str, values: &[f64], nonneg: bool) -> Result<(), String> {
    match values
        .iter()
        .find(|x| !x.is_finite() || (nonneg && **x < 0.0))
    {
        Some(x) => Err(format!(
            "{}: damaged checkpoint: {what} holds {x}{}",
            path.display(),
            if nonneg && x.is_finite() {
                " (must be >= 0)"
            } else {
                ""
            }
        )),
        None => Ok(()),
    }
}
