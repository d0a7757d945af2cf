//! What a container holds: parameters, input hashes, array specs
//! (shape, chunking, element type) and the metadata block.

use super::*;

/// A named parameter value in an artifact's metadata.
#[derive(Clone, Debug, PartialEq, Encode, Decode)]
pub enum Param {
    Int(i64),
    Float(f64),
    Text(String),
    Floats(Vec<f64>),
}

impl std::fmt::Display for Param {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Param::Int(v) => write!(f, "{v}"),
            Param::Float(v) => write!(f, "{v}"),
            Param::Text(v) => write!(f, "{v:?}"),
            Param::Floats(v) if v.len() > 8 => write!(f, "[{} values]", v.len()),
            Param::Floats(v) => write!(f, "{v:?}"),
        }
    }
}

/// The hash of one input an artifact was made from.
#[derive(Clone, Debug, PartialEq, Encode, Decode)]
pub struct InputHash {
    /// What the input was (e.g. a file name or role).
    pub name: String,
    /// xxh3-64 of its content (for containers: of their metadata and index).
    pub hash: u64,
}

/// Shape and chunking of one named array.
#[derive(Clone, Debug, PartialEq, Eq, Encode, Decode)]
pub struct ArraySpec {
    pub name: String,
    pub dtype: DType,
    /// Extent per dimension, slowest first (row-major).
    pub shape: Vec<u64>,
    /// Chunk extent per dimension; edge chunks are clipped to the shape.
    pub chunk_shape: Vec<u64>,
}

impl ArraySpec {
    /// A spec; errors if it breaks a rule of [`ArraySpec::check`] (the
    /// dimensions disagree, a chunk extent is zero, a chunk is too large...).
    pub fn new(name: &str, dtype: DType, shape: &[u64], chunk_shape: &[u64]) -> Result<ArraySpec> {
        let spec = ArraySpec {
            name: name.to_string(),
            dtype,
            shape: shape.to_vec(),
            chunk_shape: chunk_shape.to_vec(),
        };
        spec.check()
            .map_err(|reason| Error::Config(format!("array '{name}': {reason}")))?;
        Ok(spec)
    }

    /// Checks that the spec can be read without overflow or an outsize
    /// allocation: 1..=[`MAX_DIMS`] dimensions, as many chunk extents as
    /// shape extents, every chunk extent positive, element and chunk counts
    /// that fit in `u64`, at most [`MAX_ARRAY_BYTES`] in all and at most
    /// [`MAX_CHUNK_BYTES`] per decoded chunk. Every other method of the spec
    /// assumes this holds; readers check it when opening a file, writers in
    /// [`ArraySpec::new`]. The error says what is wrong (the caller names
    /// the file and array).
    pub fn check(&self) -> std::result::Result<(), String> {
        let (shape, chunk) = (&self.shape, &self.chunk_shape);
        if shape.is_empty() || shape.len() > MAX_DIMS || shape.len() != chunk.len() {
            return Err(format!(
                "shape {shape:?} and chunk shape {chunk:?} must have the same number of dimensions, 1 to {MAX_DIMS}"
            ));
        }
        if chunk.iter().any(|&c| c == 0) {
            return Err(format!("chunk extents must be positive, got {chunk:?}"));
        }
        let size = self.dtype.size() as u64;
        let bytes = shape
            .iter()
            .try_fold(size, |acc, &s| acc.checked_mul(s))
            .filter(|&b| b <= MAX_ARRAY_BYTES);
        if bytes.is_none() {
            return Err(format!(
                "shape {shape:?} of {} exceeds the {} an array may hold",
                self.dtype.name(),
                human_bytes(MAX_ARRAY_BYTES)
            ));
        }
        // the largest (unclipped) chunk actually inside the shape
        let chunk_bytes = shape
            .iter()
            .zip(chunk)
            .try_fold(size, |acc, (&s, &c)| acc.checked_mul(s.min(c)))
            .filter(|&b| b <= MAX_CHUNK_BYTES);
        if chunk_bytes.is_none() {
            return Err(format!(
                "chunk shape {chunk:?} of {} exceeds the {} a decoded chunk may hold",
                self.dtype.name(),
                human_bytes(MAX_CHUNK_BYTES)
            ));
        }
        // the chunk grid is at most the element count, which fits (above)
        Ok(())
    }

    /// Number of chunks along each dimension.
    pub fn chunk_grid(&self) -> Vec<u64> {
        self.shape
            .iter()
            .zip(&self.chunk_shape)
            .map(|(&s, &c)| s.div_ceil(c))
            .collect()
    }

    /// Total number of chunks.
    pub fn chunk_count(&self) -> u64 {
        self.chunk_grid().iter().product()
    }

    /// Total number of elements.
    pub fn len(&self) -> u64 {
        self.shape.iter().product()
    }

    /// Whether the array has no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Raw (decoded) size in bytes.
    pub fn raw_bytes(&self) -> u64 {
        self.len() * self.dtype.size() as u64
    }

    /// Linear chunk index of chunk-grid coordinates (row-major).
    pub fn chunk_index(&self, coords: &[u64]) -> u64 {
        let grid = self.chunk_grid();
        coords.iter().zip(&grid).fold(0, |acc, (&c, &g)| {
            debug_assert!(c < g);
            acc * g + c
        })
    }

    /// Chunk-grid coordinates of a linear chunk index.
    pub fn chunk_coords(&self, mut index: u64) -> Vec<u64> {
        let grid = self.chunk_grid();
        let mut coords = vec![0; grid.len()];
        for d in (0..grid.len()).rev() {
            coords[d] = index % grid[d];
            index /= grid[d];
        }
        coords
    }

    /// Element origin and clipped extent of a chunk.
    pub fn chunk_region(&self, index: u64) -> (Vec<u64>, Vec<u64>) {
        let coords = self.chunk_coords(index);
        let origin: Vec<u64> = coords
            .iter()
            .zip(&self.chunk_shape)
            .map(|(&c, &s)| c * s)
            .collect();
        let extent = origin
            .iter()
            .zip(&self.chunk_shape)
            .zip(&self.shape)
            .map(|((&o, &c), &s)| c.min(s - o))
            .collect();
        (origin, extent)
    }

    /// Number of elements in a (possibly clipped) chunk.
    pub fn chunk_len(&self, index: u64) -> usize {
        self.chunk_region(index).1.iter().product::<u64>() as usize
    }
}

/// Everything an artifact says about itself.
#[derive(Clone, Debug, PartialEq, Encode, Decode)]
pub struct Metadata {
    /// What the artifact is: "btf", "svd", "gim", "quilt", ...
    pub kind: String,
    /// The program that wrote it (name and version, no time stamp).
    pub producer: String,
    /// The seed of any random choice made while producing it.
    pub seed: Option<u64>,
    /// Hashes of the inputs it was made from.
    pub inputs: Vec<InputHash>,
    /// Named parameters, in insertion order.
    pub params: Vec<(String, Param)>,
    /// The arrays, in declaration order.
    pub arrays: Vec<ArraySpec>,
}

impl Metadata {
    /// A parameter by name.
    pub fn param(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|(k, _)| k == name).map(|(_, v)| v)
    }
}
