# The pipeline: gmsh meshes → Rust FE + Uzawa → HDF5 results → tables.
#   make          the thesis membrane scenes end to end (Tables 5.1–5.4 with our numbers)
#   make test     the test suite
#   make deps     install the Debian packages (gmsh, FreeFEM, HDF5, ...) if missing
CARGO ?= cargo
BIN := target/release/obstacle
BUILD := build
STUDIES := $(BUILD)/studies

.PHONY: all deps build test membrane-tables membrane-convergence solve clean

all: membrane-tables membrane-convergence

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

# One scene: make solve SCENE=pipelines/scenes/obstacle-disk.toml [SET="mesh.n=32 solver.alpha=0.9"]
SCENE ?= pipelines/scenes/obstacle-disk.toml
SET ?=
solve: build
	$(BIN) solve $(SCENE) $(foreach s,$(SET),--set $(s)) --out $(BUILD)/results/$(basename $(notdir $(SCENE))).h5

test: deps
	$(CARGO) test --release

clean:
	rm -rf $(BUILD)
