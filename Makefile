# The pipeline: gmsh meshes → Rust FE + Uzawa → HDF5 results → tables.
#   make          the thesis scenes end to end: membrane Tables 5.1–5.4, the
#                 Naghdi shell Tables 5.5–5.8 and Fig. 5.10, with our numbers
#   make test     the test suite
#   make deps     install the Debian packages (gmsh, FreeFEM, HDF5, ...) if missing
CARGO ?= cargo
BIN := target/release/obstacle
BUILD := build
STUDIES := $(BUILD)/studies

.PHONY: all deps build test membrane-tables membrane-convergence naghdi naghdi-tables naghdi-refinement solve clean

all: membrane-tables membrane-convergence naghdi naghdi-tables naghdi-refinement

deps:
	@bash .ci/install-deps.sh

build: deps
	$(CARGO) build --release

# Thesis Tables 5.1–5.4: both pairs, h_T = 0.8 … 0.1, α = 0.9, 1.9, auto.
membrane-tables: build
	$(BIN) study pipelines/studies/membrane-thesis.toml --out-dir $(STUDIES)

# Errors and rates of converged solutions against the exact solution.
membrane-convergence: build
	$(BIN) study pipelines/studies/membrane-convergence.toml --out-dir $(STUDIES)

# The thesis' shell scenes (contact and free), with their plots, in build/results.
naghdi: build
	$(BIN) solve pipelines/scenes/naghdi-hypar.toml --out $(BUILD)/results/naghdi-hypar.h5
	$(BIN) solve pipelines/scenes/naghdi-hypar-free.toml --out $(BUILD)/results/naghdi-hypar-free.h5

# Thesis Tables 5.5 (history), 5.6/5.8 (ρ sweep), 5.7 (α sweep).
naghdi-tables: build
	$(BIN) study pipelines/studies/naghdi-history.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/naghdi-rho.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/naghdi-alpha.toml --out-dir $(STUDIES)

# Thesis Fig. 5.10: n = 16 … 128, errors against the finest mesh, fitted rates.
naghdi-refinement: build
	$(BIN) study pipelines/studies/naghdi-refinement.toml --out-dir $(STUDIES)

# One scene: make solve SCENE=pipelines/scenes/obstacle-disk.toml [SET="mesh.n=32 solver.alpha=0.9"]
SCENE ?= pipelines/scenes/obstacle-disk.toml
SET ?=
solve: build
	$(BIN) solve $(SCENE) $(foreach s,$(SET),--set $(s)) --out $(BUILD)/results/$(basename $(notdir $(SCENE))).h5

test: deps
	$(CARGO) test --release

clean:
	rm -rf $(BUILD)
