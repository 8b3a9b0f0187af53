//! A minimal compressed-sparse-row matrix for the reference solves.

/// A square sparse matrix in compressed-sparse-row form, `f64`.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseMatrix {
    n: usize,
    offsets: Vec<usize>,
    columns: Vec<u32>,
    values: Vec<f64>,
}

impl SparseMatrix {
    /// Assembles an `n`x`n` matrix from `(row, column, value)` triplets; duplicates are summed.
    pub fn from_triplets(n: usize, mut triplets: Vec<(u32, u32, f64)>) -> Self {
        triplets.sort_by_key(|&(r, c, _)| (r, c));
        let mut offsets = vec![0usize; n + 1];
        let mut columns = Vec::with_capacity(triplets.len());
        let mut values: Vec<f64> = Vec::with_capacity(triplets.len());
        let mut last = None;
        for (r, c, v) in triplets {
            if last == Some((r, c)) {
                *values
                    .last_mut()
                    .expect("a value was pushed for this entry") += v;
            } else {
                columns.push(c);
                values.push(v);
                offsets[r as usize + 1] += 1;
                last = Some((r, c));
            }
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        Self {
            n,
            offsets,
            columns,
            values,
        }
    }

    /// Number of rows (and columns).
    pub fn size(&self) -> usize {
        self.n
    }

    /// `out = self * x`.
    pub fn multiply(&self, x: &[f64], out: &mut [f64]) {
        for (row, o) in out.iter_mut().enumerate().take(self.n) {
            let range = self.offsets[row]..self.offsets[row + 1];
            *o = self.columns[range.clone()]
                .iter()
                .zip(&self.values[range])
                .map(|(&c, v)| v * x[c as usize])
                .sum();
        }
    }

    /// The diagonal entries.
    pub fn diagonal(&self) -> Vec<f64> {
        (0..self.n)
            .map(|row| {
                let range = self.offsets[row]..self.offsets[row + 1];
                self.columns[range.clone()]
                    .iter()
                    .zip(&self.values[range])
                    .find(|(c, _)| **c as usize == row)
                    .map_or(0.0, |(_, v)| *v)
            })
            .collect()
    }

    /// Entry `(row, column)`, zero when not stored.
    pub fn get(&self, row: usize, column: usize) -> f64 {
        let range = self.offsets[row]..self.offsets[row + 1];
        self.columns[range.clone()]
            .iter()
            .zip(&self.values[range])
            .find(|(c, _)| **c as usize == column)
            .map_or(0.0, |(_, v)| *v)
    }
}
