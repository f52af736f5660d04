//! MATLAB `.mat` files as named numeric arrays, in MATLAB's own terms: `dims` as MATLAB
//! gives them (rows, columns, pages…) and values column-major (the first index fastest).
//! Both versions labs save in: v5 (MATLAB's default `save`, `-v7`, and scipy's
//! `savemat`) and v7.3 (`save -v7.3`: HDF5 behind a 512-byte header, each variable a
//! dataset whose HDF5 shape is MATLAB's reversed, so its row-major values are already
//! MATLAB's column-major ones).

use std::path::Path;

use crate::h5::{self, H5Values};
use crate::ImportError;

/// A numeric array's values, in the type stored (image stacks stay as compact as
/// the file keeps them).
#[derive(Debug, Clone, PartialEq)]
pub enum Values {
    /// double.
    F64(Vec<f64>),
    /// single.
    F32(Vec<f32>),
    /// uint16.
    U16(Vec<u16>),
    /// uint8 (and logical).
    U8(Vec<u8>),
}

impl Values {
    /// How many values.
    pub fn len(&self) -> usize {
        match self {
            Values::F64(v) => v.len(),
            Values::F32(v) => v.len(),
            Values::U16(v) => v.len(),
            Values::U8(v) => v.len(),
        }
    }

    /// None.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `k` as f64.
    pub fn at(&self, k: usize) -> f64 {
        match self {
            Values::F64(v) => v[k],
            Values::F32(v) => v[k] as f64,
            Values::U16(v) => v[k] as f64,
            Values::U8(v) => v[k] as f64,
        }
    }

    /// Whether the values are floating point (HDR frames, not raw counts).
    pub fn is_float(&self) -> bool {
        matches!(self, Values::F64(_) | Values::F32(_))
    }

    /// From an HDF5 dataset's values.
    pub(crate) fn from_h5(v: H5Values) -> Self {
        match v {
            H5Values::F64(v) => Values::F64(v),
            H5Values::F32(v) => Values::F32(v),
            H5Values::U16(v) => Values::U16(v),
            H5Values::U8(v) => Values::U8(v),
        }
    }
}

/// One variable.
#[derive(Debug, Clone, PartialEq)]
pub struct MatArray {
    /// MATLAB's dimensions (at least two).
    pub dims: Vec<usize>,
    /// Column-major values.
    pub values: Values,
}

impl MatArray {
    /// Every value as f64 (for the small arrays: parameters and LED lists).
    pub fn to_f64(&self) -> Vec<f64> {
        (0..self.values.len()).map(|k| self.values.at(k)).collect()
    }

    /// The number of elements.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// None.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }
}

/// The variables of one `.mat` file.
pub struct MatFile {
    path: std::path::PathBuf,
    arrays: Vec<(String, MatArray)>,
    /// The MATLAB format version, "5" or "7.3".
    pub version: &'static str,
}

/// The bytes every v7.3 file starts with; v5 files start with their text header.
const HDF5_MAGIC: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

impl MatFile {
    /// Read `path` (v5 or v7.3, told apart by the HDF5 signature at byte 512).
    pub fn open(path: &Path) -> Result<Self, ImportError> {
        // Only the header tells the versions apart: a v7.3 file (often the large
        // one) is not read whole just to find out.
        let mut head = Vec::with_capacity(520);
        std::fs::File::open(path)
            .and_then(|f| std::io::Read::read_to_end(&mut std::io::Read::take(f, 520), &mut head))
            .map_err(|e| ImportError::io(path, e))?;
        if head.get(512..520) == Some(HDF5_MAGIC.as_slice()) || head.starts_with(HDF5_MAGIC) {
            return Self::open_v73(path);
        }
        let bytes = std::fs::read(path).map_err(|e| ImportError::io(path, e))?;
        if bytes.len() < 128 || !bytes.starts_with(b"MATLAB 5.0 MAT-file") {
            return Err(ImportError::file(
                path,
                "not a MATLAB .mat file (neither a v5 header nor HDF5 at byte 512)",
            ));
        }
        // The parser is a third party's: it must not take the import down on a byte
        // sequence it did not expect.
        let parsed = std::panic::catch_unwind(|| matfile::MatFile::parse(bytes.as_slice()));
        let parsed = match parsed {
            Ok(Ok(m)) => m,
            Ok(Err(e)) => return Err(ImportError::file(path, format!("MATLAB v5: {e}"))),
            Err(_) => {
                return Err(ImportError::file(
                    path,
                    "MATLAB v5: the file is damaged (its parser gave up)",
                ))
            }
        };
        let arrays = parsed
            .arrays()
            .iter()
            .map(|a| {
                use matfile::NumericData as N;
                let values = match a.data() {
                    N::Double { real, .. } => Values::F64(real.clone()),
                    N::Single { real, .. } => Values::F32(real.clone()),
                    N::UInt16 { real, .. } => Values::U16(real.clone()),
                    N::UInt8 { real, .. } => Values::U8(real.clone()),
                    N::Int8 { real, .. } => Values::F64(real.iter().map(|&v| v as f64).collect()),
                    N::Int16 { real, .. } => Values::F64(real.iter().map(|&v| v as f64).collect()),
                    N::Int32 { real, .. } => Values::F64(real.iter().map(|&v| v as f64).collect()),
                    N::UInt32 { real, .. } => Values::F64(real.iter().map(|&v| v as f64).collect()),
                    N::Int64 { real, .. } => Values::F64(real.iter().map(|&v| v as f64).collect()),
                    N::UInt64 { real, .. } => Values::F64(real.iter().map(|&v| v as f64).collect()),
                };
                (
                    a.name().to_string(),
                    MatArray {
                        dims: a.size().clone(),
                        values,
                    },
                )
            })
            .collect();
        Ok(Self {
            path: path.to_path_buf(),
            arrays,
            version: "5",
        })
    }

    fn open_v73(path: &Path) -> Result<Self, ImportError> {
        let file = h5::H5File::open(path)?;
        let mut arrays = Vec::new();
        for name in file.root_datasets()? {
            // Variables MATLAB keeps as references or structs (cells, strings) are not
            // numbers: left out, as v5's are.
            let Ok((shape, values)) = file.read_numeric(&name) else {
                continue;
            };
            let mut dims: Vec<usize> = shape.iter().rev().copied().collect();
            while dims.len() < 2 {
                dims.push(1);
            }
            arrays.push((
                name,
                MatArray {
                    dims,
                    values: Values::from_h5(values),
                },
            ));
        }
        Ok(Self {
            path: path.to_path_buf(),
            arrays,
            version: "7.3",
        })
    }

    /// The file it was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Variable `name`, if the file has it.
    pub fn find(&self, name: &str) -> Option<&MatArray> {
        self.arrays.iter().find(|(n, _)| n == name).map(|(_, a)| a)
    }

    /// Variable `name`, or an error naming it and the file.
    pub fn get(&self, name: &str) -> Result<&MatArray, ImportError> {
        self.find(name).ok_or_else(|| {
            let names: Vec<&str> = self.arrays.iter().map(|(n, _)| n.as_str()).collect();
            ImportError::field(
                &self.path,
                name,
                format!(
                    "missing (the file's numeric variables: {})",
                    if names.is_empty() {
                        "none".to_string()
                    } else {
                        names.join(", ")
                    }
                ),
            )
        })
    }

    /// The first of `names` the file has, with its name.
    pub fn first_of(&self, names: &[&'static str]) -> Option<(&'static str, &MatArray)> {
        names.iter().find_map(|&n| self.find(n).map(|a| (n, a)))
    }

    /// Variable `name` as one finite number (a 1×1 array).
    pub fn scalar(&self, name: &str) -> Result<f64, ImportError> {
        let a = self.get(name)?;
        match a.to_f64().as_slice() {
            [v] if v.is_finite() => Ok(*v),
            [v] => Err(ImportError::field(
                &self.path,
                name,
                format!("{v} is not finite"),
            )),
            _ => Err(ImportError::field(
                &self.path,
                name,
                format!("holds {} values (dims {:?}); one expected", a.len(), a.dims),
            )),
        }
    }

    /// Variable `name` as a number if present.
    pub fn scalar_opt(&self, name: &str) -> Result<Option<f64>, ImportError> {
        match self.find(name) {
            Some(_) => self.scalar(name).map(Some),
            None => Ok(None),
        }
    }
}
