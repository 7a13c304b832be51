//! Assembly's sparse compression (`Triplets::into_sparse`), property-tested.

use proptest::prelude::*;

proptest! {
    /// `Triplets::into_sparse` (in-place bucket sort, duplicates summed)
    /// equals the dense sum of the entries, keeps explicit zeros in the
    /// pattern and gives sorted, unique rows per column, whatever the order
    /// and multiplicity of the entries.
    #[test]
    fn triplets_compress_to_their_dense_sum(
        nrows in 1usize..40,
        ncols in 1usize..2100,
        raw in proptest::collection::vec((0usize..1000, 0usize..100_000, -3i32..4), 0..3000),
    ) {
        use obstacle_fem::assembly::Triplets;
        let mut t = Triplets::new(nrows, ncols);
        let mut dense = vec![0.0f64; nrows * ncols];
        let mut present = vec![false; nrows * ncols];
        for &(r, c, v) in &raw {
            let (r, c, v) = (r % nrows, c % ncols, f64::from(v));
            t.push(r, c, v);
            dense[c * nrows + r] += v;
            present[c * nrows + r] = true;
        }
        let a = t.into_sparse();
        prop_assert_eq!((a.nrows(), a.ncols()), (nrows, ncols));
        let mut seen = vec![false; nrows * ncols];
        for j in 0..ncols {
            let rows: Vec<usize> = a.symbolic().row_idx_of_col(j).collect();
            prop_assert!(rows.windows(2).all(|w| w[0] < w[1]), "column {} rows {:?}", j, rows);
            for (i, &v) in rows.iter().zip(a.val_of_col(j)) {
                prop_assert_eq!(v, dense[j * nrows + i]);
                seen[j * nrows + i] = true;
            }
        }
        prop_assert_eq!(seen, present);
    }
}
