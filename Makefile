# The pipeline: gmsh meshes → Rust FE + Uzawa → HDF5 results → tables.
#   make          the thesis scenes end to end: membrane Tables 5.1–5.4, the
#                 Naghdi shell Tables 5.5–5.8 and Fig. 5.10, with our numbers;
#                 ends with build/index.html (every table, figure and result)
#   make test     the test suite
#   make deps     install the Debian packages (gmsh, FreeFEM, HDF5, ...) if missing
CARGO ?= cargo
# The binary cargo builds: below $(CARGO_TARGET_DIR) when that is set
# (`make all CARGO_TARGET_DIR=/elsewhere`), else below target/.
BIN := $(if $(CARGO_TARGET_DIR),$(CARGO_TARGET_DIR),target)/release/obstacle
BUILD := build
STUDIES := $(BUILD)/studies

.PHONY: all deps build test membrane-tables membrane-convergence naghdi naghdi-tables naghdi-refinement solve clean index

# The index comes last (a recipe, not a prerequisite: also last under make -j).
all: membrane-tables membrane-convergence naghdi naghdi-tables naghdi-refinement
	@$(MAKE) --no-print-directory index

# build/index.html: every run's status, every study table (from its CSV),
# every figure, under build/results and build/studies; and a report page
# beside every run (failed runs included).
index: build
	$(BIN) index $(BUILD)

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

# Issue 6: the hard cases (pipelines/scenes/hard/, docs/hard-cases.md) as one
# table: case, outcome, iterations, KKT measures, condition estimate, time.
# The contact scene on the largest mesh: HARD_LARGE_N subdivisions per side.
.PHONY: hard
HARD_LARGE_N ?= 96
hard: build
	$(BIN) hard pipelines/scenes/hard --set mesh-large:mesh.n=$(HARD_LARGE_N) --out-dir $(BUILD)/hard

# Issue 4: the FreeFEM cross-check (freefem/*.edp, `obstacle freefem`, `obstacle compare`).
#   make freefem SCENE=... [SET="mesh.n=32"]   the scene's FreeFEM twin → build/freefem/<name>.h5
#   make compare SCENE=... [SET=...] [K=100]   Rust and FreeFEM, exactly K Uzawa iterations each, compared
#   make compare-all                           every thesis scene both ways, one table
#   make freefem-timings                       Rust vs FreeFEM time, same mesh/algorithm/K
#   make threads-timings                       solver.threads = 1 vs 2 (factorisation, Uzawa iteration)
.PHONY: freefem compare compare-all freefem-timings threads-timings
FREEFEM_OUT := $(BUILD)/freefem
K ?= 100
RTOL ?= 1e-8
# Exactly K iterations on both sides: the thesis stop with a tolerance never met; no plots.
FIXED_K = --set solver.stop=thesis --set solver.thesis_tol=1e-300 --set solver.max_iter=$(K) --set 'output.plots=[]'
# A FIXED_K solve ends on max_iter by design: exit status 2 ("not converged", README) is its success.
FIXED_K_OK = || [ $$? -eq 2 ]
FF_SETS = $(foreach s,$(SET),--set $(s))
FF_NAME = $(basename $(notdir $(SCENE)))
# scene:overrides, the scene below pipelines/scenes/ without .toml, the overrides
# KEY=VALUE joined by commas (empty: the scene as it is). shell/hypar-psri is
# the element p2b-psri (freefem/naghdi-psri.edp), run by Uzawa here; peers/two-sided
# an expression load and a two-sided obstacle (the script's scene functions).
COMPARE_CASES = obstacle-disk:element=p1b-p0 obstacle-disk:element=p2-p1 naghdi-hypar: naghdi-hypar-free: \
	shell/hypar-psri:solver.method=uzawa,solver.alpha=auto,solver.step_form=mean \
	peers/two-sided:solver.method=uzawa,solver.alpha=auto,solver.step_form=mean \
	peers/two-sided:element=p2-p1,solver.method=uzawa,solver.alpha=auto,solver.step_form=mean
TIMING_CASES = naghdi-hypar:mesh.n=16 naghdi-hypar:mesh.n=32 naghdi-hypar:mesh.n=64 obstacle-disk:mesh.n=16
# The shell helpers of the two tables: wall clock, one /solver attribute of a result.
FF_SH = now() { date +%s.%N; }; \
	attr() { $(BIN) info "$$1" | awk -v k="$$2" '$$1 == k { print $$3; exit }'; }; \
	calc() { awk "BEGIN { printf \"$$1\", $$2 }"; }

freefem: build
	@mkdir -p $(FREEFEM_OUT)
	$(BIN) freefem $(SCENE) $(FF_SETS) --out $(FREEFEM_OUT)/$(FF_NAME).h5

compare: build
	@mkdir -p $(FREEFEM_OUT)
	$(BIN) solve $(SCENE) $(FF_SETS) $(FIXED_K) --quiet --out $(FREEFEM_OUT)/$(FF_NAME).rust.h5 $(FIXED_K_OK)
	$(BIN) freefem $(SCENE) $(FF_SETS) $(FIXED_K) --out $(FREEFEM_OUT)/$(FF_NAME).h5
	$(BIN) compare $(FREEFEM_OUT)/$(FF_NAME).rust.h5 $(FREEFEM_OUT)/$(FF_NAME).h5 --rtol $(RTOL)

# Difference: the larger of max|A−B|/max|A| and ‖A−B‖_L²/‖A‖_L²; times: whole processes.
compare-all: build
	@mkdir -p $(FREEFEM_OUT); $(FF_SH); status=0; \
	echo "K = $(K) Uzawa iterations on both sides"; \
	echo "| scene | field | difference | tolerance | Rust time (s) | FreeFEM time (s) |"; \
	echo "|---|---|---:|---:|---:|---:|"; \
	for c in $(COMPARE_CASES); do \
	  scene=$${c%%:*}; set=$${c#*:}; label="$$scene$${set:+ $$set}"; \
	  tag=$$(printf '%s' "$$set" | sed 's/[^,=]*=//g; s/,/-/g'); \
	  out=$(FREEFEM_OUT)/$$(printf '%s' "$$scene" | tr / -)$${tag:+-$$tag}; \
	  sets=$$(printf '%s' "$$set" | tr ',' '\n' | sed '/^$$/d; s/^/--set /'); \
	  t0=$$(now); \
	  { $(BIN) solve pipelines/scenes/$$scene.toml $$sets $(FIXED_K) --quiet --out $$out.rust.h5 \
	    > $$out.rust.log 2>&1 $(FIXED_K_OK); } || { echo "$$label: Rust run failed, see $$out.rust.log"; status=1; continue; }; \
	  t1=$$(now); \
	  $(BIN) freefem pipelines/scenes/$$scene.toml $$sets $(FIXED_K) --out $$out.h5 \
	    > $$out.log 2>&1 || { echo "$$label: FreeFEM run failed, see $$out.log"; status=1; continue; }; \
	  t2=$$(now); rt=$$(calc %.2f "$$t1 - $$t0"); ft=$$(calc %.2f "$$t2 - $$t1"); \
	  rows=$$($(BIN) compare $$out.rust.h5 $$out.h5 --rtol $(RTOL) --row "$$label" 2>&1) || status=1; \
	  echo "$$rows" | sed "s/^\(| .*|\)$$/\1 $$rt | $$ft |/"; \
	done; exit $$status

# Per iteration: Rust (solver time − factorisation)/K, KKT measures included;
# FreeFEM its loop, timed inside the script. Whole: the processes (mesh to file).
freefem-timings: build
	@mkdir -p $(FREEFEM_OUT); $(FF_SH); \
	echo "K = $(K) Uzawa iterations, same mesh, same α"; \
	echo "| case | vertices / triangles | Rust whole (s) | FreeFEM whole (s) | Rust per iteration (ms) | FreeFEM per iteration (ms) | FreeFEM / Rust per iteration |"; \
	echo "|---|---|---:|---:|---:|---:|---:|"; \
	for c in $(TIMING_CASES); do \
	  scene=$${c%%:*}; set=$${c#*:}; out=$(FREEFEM_OUT)/timing-$$scene-$${set#*=}; \
	  t0=$$(now); \
	  $(BIN) solve pipelines/scenes/$$scene.toml --set $$set $(FIXED_K) --quiet --out $$out.rust.h5 > /dev/null 2>&1 $(FIXED_K_OK) || exit 1; \
	  t1=$$(now); \
	  $(BIN) freefem pipelines/scenes/$$scene.toml --set $$set $(FIXED_K) --out $$out.h5 > /dev/null || exit 1; \
	  t2=$$(now); \
	  mesh=$$($(BIN) info $$out.h5 | awk '/^mesh:/ { print $$2 " / " $$4 }'); \
	  rw=$$(attr $$out.rust.h5 wall_seconds); rf=$$(attr $$out.rust.h5 factor_seconds); \
	  ri=$$(attr $$out.rust.h5 iterations); fp=$$(attr $$out.h5 seconds_per_iteration); \
	  rp=$$(calc %.3f "1000 * ($$rw - $$rf) / $$ri"); fpm=$$(calc %.3f "1000 * $$fp"); \
	  echo "| $$scene $$set | $$mesh | $$(calc %.2f "$$t1 - $$t0") | $$(calc %.2f "$$t2 - $$t1") | $$rp | $$fpm | $$(calc %.1f "$$fpm / $$rp") |"; \
	done

# Threads (issue 13): `solver.threads` 1 vs 2, interleaved, K Uzawa iterations each;
# factorisation (symbolic + numeric + checked solve) and per-iteration time, and the load.
THREAD_CASES = naghdi-hypar:mesh.n=64 naghdi-hypar:mesh.n=128 obstacle-disk:mesh.n=128
THREAD_REPEATS ?= 2
threads-timings: build
	@mkdir -p $(FREEFEM_OUT); $(FF_SH); \
	echo "K = $(K) Uzawa iterations; load $$(cut -d' ' -f1-3 /proc/loadavg)"; \
	echo "| case | threads | factorisation (s) | per iteration (ms) | load |"; \
	echo "|---|---:|---:|---:|---:|"; \
	for c in $(THREAD_CASES); do \
	  scene=$${c%%:*}; set=$${c#*:}; \
	  for r in $$(seq $(THREAD_REPEATS)); do for t in 1 2; do \
	    out=$(FREEFEM_OUT)/threads-$$scene-$${set#*=}-$$t; \
	    $(BIN) solve pipelines/scenes/$$scene.toml --set $$set --set solver.threads=$$t $(FIXED_K) --quiet --out $$out.h5 > /dev/null 2>&1 $(FIXED_K_OK) || exit 1; \
	    rw=$$(attr $$out.h5 wall_seconds); rf=$$(attr $$out.h5 factor_seconds); ri=$$(attr $$out.h5 iterations); \
	    echo "| $$scene $$set | $$t | $$(calc %.2f "$$rf") | $$(calc %.2f "1000 * ($$rw - $$rf) / $$ri") | $$(cut -d' ' -f1 /proc/loadavg) |"; \
	  done; done; \
	done

# --- Issue 5: benchmarks and work–precision studies (src/bench/) ----------
#   make bench   time / iterations / peak memory of every method to KKT 1e-6 and
#                1e-10 (shell n = 16…128, disk n = 8…64) against one linear
#                solve; table, CSV and plots in build/bench/ (~15 min)
#   make scale   the large runs (issue 13): shell n = 128, 256 (≥ 1e6 unknowns), the
#                disk at n = 512 (≥ 1M, both pairs; gmsh ~4 min each, hence the
#                tool timeout), p2b-psri n = 16…64 (~1 h)
#   make scale-512  the shell at n = 512 (≈ 6M unknowns) in contact to 1e-8 against
#                its floor, peak RSS per phase (~12 min, 17 GB)
#   make study   work–precision: error against time, report in build/study/

# Issue 14: the adaptive loop on the disk and the L-shape beside uniform n = 8…64, both pairs
# (build/adapt/*.md tables, *.dofs.png and *.time.png curves).
.PHONY: adapt
adapt: build
	$(BIN) adapt pipelines/scenes/obstacle-disk-adapt.toml --out-dir $(BUILD)/adapt
	$(BIN) adapt pipelines/scenes/obstacle-disk-adapt.toml --set 'element="p2-p1"' --out-dir $(BUILD)/adapt
	$(BIN) adapt pipelines/scenes/lshape-adapt.toml --out-dir $(BUILD)/adapt
	$(BIN) adapt pipelines/scenes/lshape-adapt.toml --set 'element="p2-p1"' --out-dir $(BUILD)/adapt

.PHONY: bench bench-1000 scale scale-512 study

bench: build
	$(BIN) bench run pipelines/bench/bench.toml --out-dir $(BUILD)/bench

# Target 2 of issue 5: Uzawa capped at 1000 × the active-set time (~1 h).
bench-1000: build
	$(BIN) bench run pipelines/bench/uzawa-1000.toml --out-dir $(BUILD)/bench-1000

scale: build
	ulimit -v 20000000; OBSTACLE_TOOL_TIMEOUT=3600 $(BIN) bench run pipelines/bench/scale.toml --out-dir $(BUILD)/scale

scale-512: build
	ulimit -v 23500000; OBSTACLE_TOOL_TIMEOUT=3600 $(BIN) bench run pipelines/bench/scale-512.toml --out-dir $(BUILD)/scale-512

study: build
	$(BIN) bench study --out-dir $(BUILD)/study \
	  --exact pipelines/studies/work-precision-disk.toml \
	  --exact pipelines/studies/work-precision-disk-uzawa.toml \
	  --reference pipelines/studies/work-precision-shell-reference.toml \
	  --against pipelines/studies/work-precision-shell.toml \
	  --against pipelines/studies/work-precision-shell-iterative.toml \
	  --adapt pipelines/scenes/obstacle-disk-adapt.toml \
	  --adapt pipelines/scenes/lshape-adapt.toml

# The shell elements side by side on the classical benchmarks
# (docs/shell-benchmarks.md): the thesis' p1b-p0, p2b-psri and the
# recommended p2b-mitc on the clamped plate over ε = 0.8 … 0.008 in bending
# and loaded in its plane, Cook's panel, the Scordelis–Lo roof, the pinched
# cylinder and hemisphere, the partly clamped hyperbolic paraboloid over
# t/L = 1e-2 … 1e-4 and the pressurised sphere over t/R = 1e-2 … 1e-4; the
# thesis' shell in contact with p2b-psri (n = 16 … 128) and with p2b-mitc
# (ε = 0.8 … 0.0008, n = 8 … 64), and the three elements' error in u3 min and
# ∫λ against wall time (work-precision-shell-elements-*.png).
.PHONY: shell-benchmarks plane-stress-references
shell-benchmarks: build
	$(BIN) study pipelines/studies/shell-plate.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/shell-in-plane.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/shell-cook.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/shell-roof.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/shell-pinched-cylinder.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/shell-pinched-hemisphere.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/shell-hypar.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/shell-sphere.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/naghdi-refinement-mitc.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/naghdi-refinement-psri.toml --out-dir $(STUDIES)
	$(BIN) study pipelines/studies/work-precision-shell-elements.toml --out-dir $(STUDIES)

# The plane-stress references of the in-plane benchmarks (the clamped plate
# loaded in its plane, Cook's panel): conforming P3 in FreeFEM on n = 32, 64,
# 128 (freefem/plane-stress.edp) → build/plane-stress-references.txt.
plane-stress-references:
	@mkdir -p $(BUILD)
	FF_LOADPATH=/usr/lib/freefem++ FreeFem++ -nw -v 0 freefem/plane-stress.edp > $(BUILD)/plane-stress-references.txt.tmp
	mv $(BUILD)/plane-stress-references.txt.tmp $(BUILD)/plane-stress-references.txt
	cat $(BUILD)/plane-stress-references.txt

# The thesis' shell with p2b-mitc, thin, solved adaptively at ε = 0.08,
# 0.008, 0.0008 (the load ∝ ε): per step the dofs, the estimator, u3 min,
# the contact area, ∫λ and the strain energy (`obstacle info`), in
# build/shell-thin-adapt/hypar-mitc-adapt-EPS.md (docs/shell-benchmarks.md,
# "The thin shell in contact, adaptively"). About 25 minutes; 12 GB at most.
.PHONY: shell-thin-adapt
THIN_ADAPT := $(BUILD)/shell-thin-adapt
shell-thin-adapt: build
	@mkdir -p $(THIN_ADAPT)
	$(BIN) solve pipelines/scenes/shell/hypar-mitc-adapt.toml --set shell.thickness=0.08 --set 'load.f=[0.0,0.0,-0.025]' --set adapt.max_dofs=700000 --quiet --out $(THIN_ADAPT)/hypar-mitc-adapt-0.08.h5
	$(BIN) solve pipelines/scenes/shell/hypar-mitc-adapt.toml --quiet --out $(THIN_ADAPT)/hypar-mitc-adapt-0.008.h5
	$(BIN) solve pipelines/scenes/shell/hypar-mitc-adapt.toml --set shell.thickness=0.0008 --set 'load.f=[0.0,0.0,-0.00025]' --set adapt.max_dofs=2500000 --set solver.tol=1e-8 --quiet --out $(THIN_ADAPT)/hypar-mitc-adapt-0.0008.h5
	for e in 0.08 0.008 0.0008; do $(BIN) info $(THIN_ADAPT)/hypar-mitc-adapt-$$e.h5 | sed -n '/^adaptive steps/,$$p' > $(THIN_ADAPT)/hypar-mitc-adapt-$$e.md; echo "ε = $$e"; cat $(THIN_ADAPT)/hypar-mitc-adapt-$$e.md; done

# The hard cases with the locking-free elements (every case's element set to
# p2b-psri, then to p2b-mitc; docs/hard-cases.md, second and third tables).
# Expectations are the thesis element's, so a different outcome is reported,
# not hidden.
.PHONY: hard-psri hard-mitc
hard-psri: build
	-$(BIN) hard pipelines/scenes/hard --set '*:element=p2b-psri' --set mesh-large:mesh.n=$(HARD_LARGE_N) --out-dir $(BUILD)/hard-psri
hard-mitc: build
	-$(BIN) hard pipelines/scenes/hard --set '*:element=p2b-mitc' --set mesh-large:mesh.n=$(HARD_LARGE_N) --out-dir $(BUILD)/hard-mitc

.PHONY: paraview
# The thesis shell rendered by ParaView itself (Debian's paraview: pvbatch;
# xvfb for its OpenGL context): coloured by u3, in 3D over the rigid plane and
# from above, the contact zone outlined; README shows it (docs/img).
paraview: naghdi
	mkdir -p $(BUILD)/paraview
	xvfb-run -a pvbatch pipelines/paraview/render_shell.py $(BUILD)/results/naghdi-hypar.xdmf $(BUILD)/paraview/naghdi-hypar.png

# Issue 17: peers' obstacle examples (pipelines/scenes/peers/) beside their
# published numbers, one table: build/peers/peers.md and peers.csv.
.PHONY: peers
PEERS := $(BUILD)/peers
# `obstacle info FILE` line "  KEY = VALUE" → VALUE (the first one).
info_value = $$($(BIN) info $(1) | awk -F' = ' '$$1 == "  $(2)" { print $$2; exit }')
peers: build
	@mkdir -p $(PEERS)
	$(BIN) solve pipelines/scenes/peers/step-41.toml --quiet --out $(PEERS)/step-41.h5
	$(BIN) solve pipelines/scenes/peers/freefem-vi.toml --quiet --out $(PEERS)/freefem-vi.h5
	$(BIN) solve pipelines/scenes/peers/two-sided.toml --quiet --out $(PEERS)/two-sided.h5
	FF_LOADPATH=/usr/lib/freefem++ FreeFem++ -nw -v 0 freefem/peers/vi.edp -out $(PEERS)/freefem-vi.ff > $(PEERS)/freefem-vi.ff.log 2>&1
	$(BIN) study pipelines/studies/peers-ball.toml --out-dir $(PEERS) > $(PEERS)/peers-ball.log
	@ff() { awk -v k="$$1" '$$1 == k { print $$2 }' $(PEERS)/freefem-vi.ff.info.txt; }; \
	{ echo "case,quantity,ours,peer,peer source"; \
	  echo "step-41,active multipliers (final),$(call info_value,$(PEERS)/step-41.h5,active),5399,deal.II step-41 results page (Q1 128x128)"; \
	  echo "step-41,active-set iterations,$(call info_value,$(PEERS)/step-41.h5,iterations),18,deal.II step-41 results page"; \
	  echo "freefem-vi,active upper multipliers,$(call info_value,$(PEERS)/freefem-vi.h5,active),$$(ff locked),FreeFEM tutorial VI.edp run here (P1 20x20)"; \
	  echo "freefem-vi,active-set iterations,$(call info_value,$(PEERS)/freefem-vi.h5,iterations),$$(ff iterations),FreeFEM tutorial VI.edp run here"; \
	  echo "two-sided,active multipliers (both bounds),$(call info_value,$(PEERS)/two-sided.h5,active),–,no peer (a two-sided case of ours)"; \
	} > $(PEERS)/peers.csv
	@{ echo "# Peers' obstacle examples"; echo; \
	  echo "| case | quantity | ours | peer | peer source |"; echo "|---|---|---:|---:|---|"; \
	  tail -n +2 $(PEERS)/peers.csv | sed 's/,/ | /g; s/^/| /; s/$$/ |/'; echo; \
	  cat $(PEERS)/peers-ball.md; } > $(PEERS)/peers.md
	@cat $(PEERS)/peers.md

# Issue 45: Bueler's ball obstacle beside PETSc's SNESVI (reduced-space active set,
# multigrid, grid sequencing; pipelines/peers/petsc/ball.c, built against Debian's
# petsc-dev, not installed by `make deps`) on N × N vertices for each N of SIZES
# (N − 1 = 4 · 2^K): wall time, peak RSS, max error, iterations of both codes →
# build/peers-bench/table.csv and table.md (pipelines/peers/peers-bench.sh).
.PHONY: peers-bench petsc-check
SIZES ?= 257 513 1025 2049
PEERS_BENCH := $(BUILD)/peers-bench
# PETSc's C compiler (`PCC` of its petscvariables: Debian's is mpicc).
PETSC_CC ?= mpicc
petsc-check:
	@pkg-config --exists PETSc 2>/dev/null || { echo "make peers-bench: PETSc not found (pkg-config PETSc); install Debian's petsc-dev: apt-get install petsc-dev" >&2; exit 1; }
	@command -v $(PETSC_CC) > /dev/null || { echo "make peers-bench: $(PETSC_CC), PETSc's C compiler, not found (PETSC_CC=...)" >&2; exit 1; }
$(PEERS_BENCH)/ball: pipelines/peers/petsc/ball.c | petsc-check
	@mkdir -p $(@D)
	$(PETSC_CC) -O2 -Wall $$(pkg-config --cflags PETSc) $< -o $@ $$(pkg-config --libs PETSc) -lm
peers-bench: petsc-check build $(PEERS_BENCH)/ball
	bash pipelines/peers/peers-bench.sh $(BIN) $(PEERS_BENCH)/ball $(PEERS_BENCH) $(SIZES)

# Issue 45's linear core: multigrid V-cycles and MG-preconditioned CG beside the
# direct solver on the P1 Laplacian at N² vertices for each N of MG_SIZES
# (N − 1 = 8 · 2^k): cycles, contraction, times, peak RSS (docs/solvers.md, "Multigrid").
.PHONY: multigrid-bench
MG_SIZES ?= 129 257 513 1025
multigrid-bench: deps
	$(CARGO) run --release --example multigrid_bench -- $(MG_SIZES)

# Issue 45's shell: MG-preconditioned CG beside the direct solver on the
# p2b-psri system of the hypar without its obstacle, for t/L = 1e-1 … 1e-4
# on N × N cells for each N of SHELL_MG_SIZES (N = 4 · 2^k): PCG iterations,
# times, peak RSS (docs/solvers.md, "Multigrid for the shell").
.PHONY: shell-multigrid-bench
SHELL_MG_SIZES ?= 16 32 64
shell-multigrid-bench: deps
	$(CARGO) run --release --example shell_multigrid_bench -- $(SHELL_MG_SIZES)
