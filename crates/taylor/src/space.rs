//! Monomial spaces: the dense, graded layout shared by all Taylor models of one problem.
//!
//! A polynomial in `nvars` variables up to total degree `order` is a coefficient vector indexed
//! by monomials in graded order (all degree-0 terms, then degree 1, ...). Because the layout
//! is graded, a polynomial of degree d is just a prefix of the vector, truncation is a
//! `truncate`, and a product only visits the pairs whose degrees fit. The pair tables are
//! built once per space, so the hot multiplication loop does no hashing and no allocation.
//!
//! Domains: every variable ranges over [-1, 1], except the variables in `unit_mask`, which
//! range over [0, 1] (normalised time). So every monomial is bounded by 1 in magnitude, and
//! one whose odd exponents all belong to unit variables is non-negative.
use crate::error::{Result, TaylorError};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

/// Highest supported order: products of two kept monomials must fit in a byte per variable.
pub const MAX_ORDER: usize = 60;
/// Highest number of variables (state dimensions plus time and parameters).
pub const MAX_VARS: usize = 32;

pub struct Space {
    pub nvars: usize,
    pub order: usize,
    pub unit_mask: u64,
    /// Exponents, `nvars` bytes per monomial.
    exps: Vec<u8>,
    /// Total degree of each monomial.
    pub deg: Vec<u8>,
    /// `block_end[d]` = number of monomials of degree <= d.
    pub block_end: Vec<usize>,
    /// For monomial i, `pairs[pair_start[i]..pair_start[i+1]]` = (j, index of i*j), sorted by j,
    /// for every j with deg(i) + deg(j) <= order.
    pair_start: Vec<usize>,
    pairs: Vec<(u32, u32)>,
    /// Whether the monomial is non-negative on the domain (its range is [0, 1], else [-1, 1]).
    pub nonneg: Vec<bool>,
    /// Index of monomial * x_v for each variable (u32::MAX when above `order`), row-major.
    times_var: Vec<u32>,
    /// Index of the monomial with variable v removed, and the removed exponent.
    without_var: Vec<u32>,
    /// For i >= 1: (j, v) with monomial i = monomial j * x_v (used to build powers by products).
    parent: Vec<(u32, u8)>,
}

impl Space {
    /// The shared space for these parameters (built on first use, then cached).
    pub fn get(nvars: usize, order: usize, unit_mask: u64) -> Result<Arc<Space>> {
        static CACHE: OnceLock<Mutex<HashMap<(usize, usize, u64), Arc<Space>>>> = OnceLock::new();
        if nvars == 0 || nvars > MAX_VARS {
            return Err(TaylorError::input(format!("a Taylor model needs between 1 and {MAX_VARS} variables, got {nvars}")));
        }
        if order == 0 || order > MAX_ORDER {
            return Err(TaylorError::input(format!("Taylor model order must be between 1 and {MAX_ORDER}, got {order}")));
        }
        let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
        let mut guard = cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(s) = guard.get(&(nvars, order, unit_mask)) {
            return Ok(s.clone());
        }
        let space = Arc::new(Space::build(nvars, order, unit_mask));
        guard.insert((nvars, order, unit_mask), space.clone());
        Ok(space)
    }

    fn build(nvars: usize, order: usize, unit_mask: u64) -> Space {
        let mut exps: Vec<u8> = Vec::new();
        let mut deg = Vec::new();
        let mut block_end = Vec::new();
        let mut current = vec![0u8; nvars];
        for d in 0..=order {
            enumerate(&mut current, 0, d, &mut |e| {
                exps.extend_from_slice(e);
                deg.push(d as u8);
            });
            block_end.push(deg.len());
        }
        let len = deg.len();
        let mut index: HashMap<&[u8], u32> = HashMap::with_capacity(len);
        for i in 0..len {
            index.insert(&exps[i * nvars..(i + 1) * nvars], i as u32);
        }
        let mut pair_start = Vec::with_capacity(len + 1);
        let mut pairs = Vec::new();
        let mut buf = vec![0u8; nvars];
        for i in 0..len {
            pair_start.push(pairs.len());
            let limit = block_end[order - deg[i] as usize];
            for j in 0..limit {
                for v in 0..nvars {
                    buf[v] = exps[i * nvars + v] + exps[j * nvars + v];
                }
                pairs.push((j as u32, index[&buf[..]]));
            }
        }
        pair_start.push(pairs.len());
        let nonneg = (0..len).map(|i| (0..nvars).all(|v| exps[i * nvars + v].is_multiple_of(2) || unit_mask >> v & 1 == 1)).collect();
        let mut times_var = vec![u32::MAX; len * nvars];
        let mut without_var = vec![0u32; len * nvars];
        for i in 0..len {
            for v in 0..nvars {
                buf.copy_from_slice(&exps[i * nvars..(i + 1) * nvars]);
                if (deg[i] as usize) < order {
                    buf[v] += 1;
                    times_var[i * nvars + v] = index[&buf[..]];
                    buf[v] -= 1;
                }
                buf[v] = 0;
                without_var[i * nvars + v] = index[&buf[..]];
            }
        }
        let mut parent = vec![(0u32, 0u8); len];
        for (i, p) in parent.iter_mut().enumerate().skip(1) {
            buf.copy_from_slice(&exps[i * nvars..(i + 1) * nvars]);
            let v = buf.iter().position(|&e| e > 0).unwrap_or(0);
            buf[v] -= 1;
            *p = (index[&buf[..]], v as u8);
        }
        drop(index);
        Space { nvars, order, unit_mask, exps, deg, block_end, pair_start, pairs, nonneg, times_var, without_var, parent }
    }

    pub fn len(&self) -> usize {
        self.deg.len()
    }
    pub fn is_empty(&self) -> bool {
        self.deg.is_empty()
    }
    /// Number of monomials of degree <= d.
    pub fn len_upto(&self, d: usize) -> usize {
        self.block_end[d.min(self.order)]
    }
    pub fn exponents(&self, i: usize) -> &[u8] {
        &self.exps[i * self.nvars..(i + 1) * self.nvars]
    }
    pub fn exponent(&self, i: usize, v: usize) -> u8 {
        self.exps[i * self.nvars + v]
    }
    /// Index of the degree-1 monomial x_v.
    pub fn var_index(&self, v: usize) -> usize {
        1 + v
    }
    #[inline]
    pub fn pairs_of(&self, i: usize) -> &[(u32, u32)] {
        &self.pairs[self.pair_start[i]..self.pair_start[i + 1]]
    }
    #[inline]
    pub fn times_var(&self, i: usize, v: usize) -> Option<usize> {
        let k = self.times_var[i * self.nvars + v];
        (k != u32::MAX).then_some(k as usize)
    }
    #[inline]
    pub fn without_var(&self, i: usize, v: usize) -> usize {
        self.without_var[i * self.nvars + v] as usize
    }
    /// For monomial i >= 1, a monomial j and variable v with i = j * x_v.
    #[inline]
    pub fn parent(&self, i: usize) -> (usize, usize) {
        let (j, v) = self.parent[i];
        (j as usize, v as usize)
    }
    pub fn is_unit(&self, v: usize) -> bool {
        self.unit_mask >> v & 1 == 1
    }
}

/// Calls `f` for every exponent vector with the given total degree over variables `v..`,
/// in reverse-lexicographic order so that x_0 comes first within a degree block.
fn enumerate(e: &mut [u8], v: usize, remaining: usize, f: &mut dyn FnMut(&[u8])) {
    if v == e.len() - 1 {
        e[v] = remaining as u8;
        f(e);
        e[v] = 0;
        return;
    }
    for k in (0..=remaining).rev() {
        e[v] = k as u8;
        enumerate(e, v + 1, remaining - k, f);
    }
    e[v] = 0;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn binomial(n: usize, k: usize) -> usize {
        (0..k).fold(1, |acc, i| acc * (n - i) / (i + 1))
    }

    #[test]
    fn counts_and_layout() {
        let s = Space::get(3, 4, 0).unwrap();
        assert_eq!(s.len(), binomial(3 + 4, 4));
        assert_eq!(s.exponents(0), &[0, 0, 0]);
        for v in 0..3 {
            let i = s.var_index(v);
            assert_eq!(s.deg[i], 1);
            assert_eq!(s.exponent(i, v), 1);
        }
    }

    #[test]
    fn pair_table_multiplies_exponents() {
        let s = Space::get(2, 5, 1).unwrap();
        for i in 0..s.len() {
            for &(j, k) in s.pairs_of(i) {
                for v in 0..2 {
                    assert_eq!(s.exponent(k as usize, v), s.exponent(i, v) + s.exponent(j as usize, v));
                }
            }
        }
        // x0 is a unit variable: x0 is non-negative, x1 is not, x1^2 is.
        assert!(s.nonneg[s.var_index(0)]);
        assert!(!s.nonneg[s.var_index(1)]);
    }

    #[test]
    fn bad_parameters_are_errors() {
        assert!(Space::get(0, 3, 0).is_err());
        assert!(Space::get(2, 0, 0).is_err());
        assert!(Space::get(2, MAX_ORDER + 1, 0).is_err());
    }
}
