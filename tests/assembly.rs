//! Assembly: sparse compression (`Triplets::into_sparse`) and element-by-element
//! assembly into compressed columns (`ElementMatrix`), property-tested; the P0
//! rows and constant loads from basis means against quadrature.

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

    /// `ElementMatrix` holds exactly the couplings of its elements (coupled
    /// dofs with each other and with the multipliers, never two
    /// multipliers; explicit zeros kept; eliminated dofs dropped) and sums
    /// the elements' blocks to what `Triplets::into_sparse` gives for the
    /// same entries.
    #[test]
    fn element_matrix_equals_the_triplet_sum_on_the_elements_pattern(
        n in 1usize..30,
        elements in proptest::collection::vec(
            (proptest::collection::vec(0usize..1000, 1..6), proptest::collection::vec(0usize..1000, 0..3)),
            1..40,
        ),
        eliminated in proptest::collection::vec(any::<bool>(), 30),
    ) {
        use obstacle_fem::assembly::{ElementMatrix, Triplets};
        // Element e: distinct global dofs, the first `k` coupled; a dof's
        // free index or None where eliminated.
        let n_free = (0..n).filter(|&d| !eliminated[d]).count();
        prop_assume!(n_free > 0);
        let free = |d: usize| -> Option<usize> {
            (!eliminated[d]).then(|| (0..d).filter(|&k| !eliminated[k]).count())
        };
        let lists: Vec<(Vec<usize>, Vec<usize>)> = elements
            .iter()
            .map(|(coupled, multipliers)| {
                let mut all: Vec<usize> = coupled.iter().chain(multipliers).map(|d| d % n).collect();
                all.sort_unstable();
                all.dedup();
                let k = coupled.len().min(all.len());
                (all[..k].to_vec(), all[k..].to_vec())
            })
            .collect();
        let value = |e: usize, a: usize, b: usize| ((e * 7 + a * 3 + b) % 5) as f64 - 2.0;
        let mut m = ElementMatrix::new(n_free, lists.len(), |e, dofs| {
            dofs.coupled.extend(lists[e].0.iter().filter_map(|&d| free(d)));
            dofs.multipliers.extend(lists[e].1.iter().filter_map(|&d| free(d)));
        });
        let mut t = Triplets::new(n_free, n_free);
        for (e, (coupled, multipliers)) in lists.iter().enumerate() {
            let k = coupled.len();
            let dofs: Vec<Option<usize>> = coupled.iter().chain(multipliers).map(|&d| free(d)).collect();
            let couples = |a: usize, b: usize| a < k || b < k;
            m.add(&dofs, |a, b| if couples(a, b) { value(e, a, b) } else { 0.0 });
            for (a, i) in dofs.iter().enumerate() {
                for (b, j) in dofs.iter().enumerate() {
                    if let (Some(i), Some(j), true) = (i, j, couples(a, b)) {
                        t.push(*i, *j, value(e, a, b));
                    }
                }
            }
        }
        let (a, b) = (m.into_sparse(), t.into_sparse());
        prop_assert_eq!(common::pattern(&a), common::pattern(&b));
        // Small integers: every order of summation is exact.
        prop_assert_eq!(a.val(), b.val());
    }
}

mod common;

/// The P0 constraint rows and a constant load from the basis means equal
/// quadrature's on every element, with boundary dofs eliminated and their
/// values shifted to the right: to round-off (1e-14 of the row's size).
/// The structured square of `n` × `n` cells with its interior vertices
/// moved: triangles of different shapes and sizes.
fn perturbed_square(n: usize) -> obstacle_fem::mesh::Mesh {
    let mut mesh = common::square_mesh(n);
    for (k, v) in mesh.vertices.iter_mut().enumerate() {
        if v[0].abs() < 1.0 && v[1].abs() < 1.0 {
            v[0] += 0.05 * ((k * 7 % 5) as f64 - 2.0) / 2.0;
            v[1] += 0.05 * ((k * 3 % 5) as f64 - 2.0) / 2.0;
        }
    }
    mesh
}

/// Each of `ours` within 1e-14 of the largest |theirs| of its twin (equal
/// where `theirs` is all zero).
fn assert_within_round_off(what: &str, ours: &[f64], theirs: &[f64]) {
    assert_eq!(ours.len(), theirs.len(), "{what}: lengths");
    let scale = theirs.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (a, b) in ours.iter().zip(theirs) {
        assert!(
            (a - b).abs() <= 1e-14 * scale,
            "{what}: {a:e} against {b:e}"
        );
    }
}

#[test]
fn p0_mass_and_constant_load_from_basis_means_equal_quadrature() {
    use obstacle_fem::assembly::{
        assemble_bilinear_eliminated, assemble_constant_linear, assemble_linear, assemble_p0_mass,
        mass, DofNumbering,
    };
    use obstacle_fem::quadrature::TriangleRule;
    use obstacle_fem::space::{Element, Space};
    let mesh = perturbed_square(6);
    let p0 = Space::new(&mesh, Element::P0);
    let rule = TriangleRule::exact_for(6);
    for element in [
        Element::P1,
        Element::P1Bubble,
        Element::P2,
        Element::P2Bubble,
    ] {
        let u = Space::new(&mesh, element);
        let numbering = DofNumbering::from_fixed_mask(&u.boundary_dof_mask(None));
        let fixed: Vec<f64> = (0..u.n_dofs()).map(|d| 1.0 + (d % 7) as f64).collect();
        let (c, shift) = assemble_p0_mass(&u, &numbering, &fixed);
        let (q, q_shift) = assemble_bilinear_eliminated(
            &p0,
            &u,
            &rule,
            mass,
            &DofNumbering::all_free(p0.n_dofs()),
            &numbering,
            &fixed,
        );
        assert_eq!(common::pattern(&c), common::pattern(&q), "{element:?}");
        let load = assemble_constant_linear(&u, 2.5);
        let quadrature = assemble_linear(&u, &rule, |v, _| 2.5 * v.value);
        for (what, ours, theirs) in [
            ("C", c.val(), q.val()),
            ("the boundary values' shift", &shift[..], &q_shift[..]),
            ("the load", &load[..], &quadrature[..]),
        ] {
            assert_within_round_off(&format!("{element:?}, {what}"), ours, theirs);
        }
    }
}

/// The P1 stiffness built from the mesh's edges equals the general element
/// loop's (the Laplacian at a one-point rule, exact for P1) on a mesh of
/// triangles of different shapes, with the boundary vertices eliminated
/// and their values shifted to the right: the same pattern, the values
/// and the shift to round-off (1e-14 of the largest).
#[test]
fn p1_stiffness_from_edges_equals_the_element_loop() {
    use obstacle_fem::assembly::{
        assemble_bilinear_eliminated, laplace, p1_stiffness, DofNumbering,
    };
    use obstacle_fem::quadrature::TriangleRule;
    use obstacle_fem::space::{Element, Space};
    let mesh = perturbed_square(7);
    let u = Space::new(&mesh, Element::P1);
    for numbering in [
        DofNumbering::from_fixed_mask(&u.boundary_dof_mask(None)),
        DofNumbering::all_free(u.n_dofs()),
    ] {
        let fixed: Vec<f64> = (0..u.n_dofs()).map(|d| 1.0 + (d % 7) as f64).collect();
        let (k, shift) = p1_stiffness(&mesh, &numbering, &fixed, 0);
        let (q, q_shift) = assemble_bilinear_eliminated(
            &u,
            &u,
            &TriangleRule::exact_for(0),
            laplace,
            &numbering,
            &numbering,
            &fixed,
        );
        assert_eq!(common::pattern(&k), common::pattern(&q));
        for (what, ours, theirs) in [
            ("K", k.val(), q.val()),
            ("the boundary values' shift", &shift[..], &q_shift[..]),
        ] {
            let nonzero = theirs.iter().any(|&v| v != 0.0);
            assert!(nonzero || numbering.n_free() == u.n_dofs(), "{what}");
            assert_within_round_off(what, ours, theirs);
        }
    }
}
