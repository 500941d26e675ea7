//! Disjoint sets (union–find) over `0..n`, for connected regions found run by run: the
//! tactile hole filling and the stereo speckle filter join runs of pixels this way
//! instead of flood-filling pixel by pixel.

/// Disjoint sets of `0..n`; every set is named by its smallest member.
#[derive(Debug, Clone)]
pub struct DisjointSets {
    parent: Vec<u32>,
}

impl DisjointSets {
    /// `n` singletons. `n` must fit a `u32` (runs of a frame always do).
    pub fn new(n: usize) -> Self {
        assert!(u32::try_from(n).is_ok(), "at most 2^32 elements");
        Self {
            parent: (0..n as u32).collect(),
        }
    }

    /// The number of elements.
    pub fn len(&self) -> usize {
        self.parent.len()
    }

    /// `true` with no elements.
    pub fn is_empty(&self) -> bool {
        self.parent.is_empty()
    }

    /// The smallest member of `i`'s set (halving the path on the way).
    pub fn root(&mut self, i: usize) -> usize {
        let p = &mut self.parent;
        let mut i = i as u32;
        while p[i as usize] != i {
            p[i as usize] = p[p[i as usize] as usize];
            i = p[i as usize];
        }
        i as usize
    }

    /// Joins the sets of `a` and `b`.
    pub fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.root(a), self.root(b));
        self.parent[ra.max(rb)] = ra.min(rb) as u32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_join_and_are_named_by_their_smallest_member() {
        let mut s = DisjointSets::new(8);
        assert_eq!(s.len(), 8);
        s.union(5, 3);
        s.union(7, 5);
        s.union(1, 2);
        assert_eq!([s.root(7), s.root(5), s.root(3)], [3; 3]);
        assert_eq!([s.root(2), s.root(1)], [1; 2]);
        assert_eq!([s.root(0), s.root(4), s.root(6)], [0, 4, 6]);
        s.union(2, 7);
        assert!(
            (1..=7)
                .filter(|i| ![4, 6].contains(i))
                .all(|i| s.root(i) == 1)
        );
        assert!(DisjointSets::new(0).is_empty());
    }
}
