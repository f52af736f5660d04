//! HDF5 files (MATLAB v7.3, PtyLab) through a pure-Rust reader: numeric datasets by
//! name, in the file's row-major order, with errors naming the file and dataset.

use std::path::{Path, PathBuf};

use hdf5_reader::{Datatype, Hdf5File};

use crate::ImportError;

/// A dataset's values in the type stored (integers other than 8/16-bit unsigned as
/// f64).
#[derive(Debug, Clone, PartialEq)]
pub enum H5Values {
    /// 64-bit float.
    F64(Vec<f64>),
    /// 32-bit float.
    F32(Vec<f32>),
    /// 16-bit unsigned.
    U16(Vec<u16>),
    /// 8-bit unsigned.
    U8(Vec<u8>),
}

impl H5Values {
    /// Every value as f64.
    pub fn to_f64(&self) -> Vec<f64> {
        match self {
            H5Values::F64(v) => v.clone(),
            H5Values::F32(v) => v.iter().map(|&x| x as f64).collect(),
            H5Values::U16(v) => v.iter().map(|&x| x as f64).collect(),
            H5Values::U8(v) => v.iter().map(|&x| x as f64).collect(),
        }
    }
}

/// An open HDF5 file.
pub struct H5File {
    path: PathBuf,
    file: Hdf5File,
}

impl H5File {
    /// Open `path` (a user block, as MATLAB writes, is skipped).
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        let file = Hdf5File::open(path)
            .map_err(|e| ImportError::file(path, format!("not a readable HDF5 file: {e}")))?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
        })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The names of the datasets in the root group.
    pub fn root_datasets(&self) -> Result<Vec<String>, ImportError> {
        let root = self
            .file
            .root_group()
            .map_err(|e| ImportError::file(&self.path, format!("HDF5 root group: {e}")))?;
        let datasets = root
            .datasets()
            .map_err(|e| ImportError::file(&self.path, format!("HDF5 root group: {e}")))?;
        Ok(datasets
            .iter()
            .map(|d| d.name().trim_start_matches('/').to_string())
            .collect())
    }

    /// Whether the file has dataset `name`.
    pub fn has(&self, name: &str) -> bool {
        self.file.dataset(name).is_ok()
    }

    /// Dataset `name`: its shape (row-major, as HDF5 and NumPy give it) and values.
    pub fn read_numeric(&self, name: &str) -> Result<(Vec<usize>, H5Values), ImportError> {
        let field = |why: String| ImportError::field(&self.path, name, why);
        let ds = self
            .file
            .dataset(name)
            .map_err(|e| field(format!("missing ({e})")))?;
        let shape: Vec<usize> = ds.shape().iter().map(|&d| d as usize).collect();
        let read = |e: hdf5_reader::error::Error| field(format!("unreadable: {e}"));
        // In the array's logical (row-major) order, whatever its memory layout.
        macro_rules! read_as {
            ($t:ty) => {
                ds.read_array::<$t>()
                    .map_err(read)?
                    .iter()
                    .copied()
                    .collect::<Vec<$t>>()
            };
        }
        macro_rules! ints {
            ($t:ty) => {
                ds.read_array::<$t>()
                    .map_err(read)?
                    .iter()
                    .map(|&v| v as f64)
                    .collect::<Vec<f64>>()
            };
        }
        let values = match ds.dtype() {
            Datatype::FloatingPoint { size: 8, .. } => H5Values::F64(read_as!(f64)),
            Datatype::FloatingPoint { size: 4, .. } => H5Values::F32(read_as!(f32)),
            Datatype::FixedPoint {
                size: 2,
                signed: false,
                ..
            } => H5Values::U16(read_as!(u16)),
            Datatype::FixedPoint {
                size: 1,
                signed: false,
                ..
            } => H5Values::U8(read_as!(u8)),
            Datatype::FixedPoint { size, signed, .. } => H5Values::F64(match (size, signed) {
                (1, true) => ints!(i8),
                (2, true) => ints!(i16),
                (4, true) => ints!(i32),
                (4, false) => ints!(u32),
                (8, true) => ints!(i64),
                (8, false) => ints!(u64),
                _ => {
                    return Err(field(format!(
                        "integers of {size} bytes are not numbers fpm reads"
                    )))
                }
            }),
            other => return Err(field(format!("not numeric ({other:?})"))),
        };
        Ok((shape, values))
    }

    /// Dataset `name` as one finite number (any shape holding one value).
    pub fn scalar(&self, name: &str) -> Result<f64, ImportError> {
        let (shape, values) = self.read_numeric(name)?;
        match values.to_f64().as_slice() {
            [v] if v.is_finite() => Ok(*v),
            _ => Err(ImportError::field(
                &self.path,
                name,
                format!("shape {shape:?}: one finite number expected"),
            )),
        }
    }

    /// Dataset `name` as a number if present.
    pub fn scalar_opt(&self, name: &str) -> Result<Option<f64>, ImportError> {
        if self.has(name) {
            self.scalar(name).map(Some)
        } else {
            Ok(None)
        }
    }
}
