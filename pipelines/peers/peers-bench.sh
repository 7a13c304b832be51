#!/usr/bin/env bash
# `make peers-bench` (issue 45): Bueler's ball obstacle (pipelines/scenes/peers/ball.toml)
# solved by PETSc's SNESVI (pipelines/peers/petsc/ball.c: reduced-space active set,
# multigrid, grid sequencing from a 5 × 5 grid) and by ours (Newton multigrid, grid
# sequencing from the 4 × 4-cell rectangle: pipelines/scenes/peers/ball-multigrid.toml)
# on N × N vertices for each N of SIZES; one process per run, the same K refinements.
#
#   peers-bench.sh BIN PETSC_BALL OUT_DIR N...    (each N − 1 = 4 · 2^K)
#
# Per run: whole-process wall time and peak RSS (/usr/bin/time), max |u − u_exact| over
# the vertices, Newton iterations on the finest level (PETSc's per level and total go to
# the Markdown). Writes OUT_DIR/table.csv (code,vertices,wall_seconds,max_error,
# iterations,peak_rss_mb) and OUT_DIR/table.md (both codes per size, ratio ours/PETSc).
# A run that fails (our memory guard refusing a size, say) is a row with empty error and
# iterations, its reason in the Markdown, and the next size runs. Our memory guard's limit
# is MEMORY_LIMIT_GB in GB of 10⁹ bytes, as mesh.memory_limit_gb (default 0.9 × MemTotal;
# the guard's own default, half of MemAvailable, refuses 4097²).
set -uo pipefail
[ $# -ge 4 ] || { echo "usage: $0 BIN PETSC_BALL OUT_DIR N..." >&2; exit 2; }
bin=$1 ball=$2 out=$3
shift 3
scene=pipelines/scenes/peers/ball-multigrid.toml
mkdir -p "$out"
csv=$out/table.csv md=$out/table.md notes=$out/notes.txt cpu=$out/cpu.csv
echo "code,vertices,wall_seconds,max_error,iterations,peak_rss_mb" > "$csv"
: > "$notes"
: > "$cpu"
memory_gb=${MEMORY_LIMIT_GB:-$(awk '$1 == "MemTotal:" { printf "%.1f", 0.9 * $2 * 1024 / 1e9 }' /proc/meminfo)}
load_start=$(cut -d' ' -f1-3 /proc/loadavg)

# `/usr/bin/time -f "%e %M %U %S"` output (its last line) → "wall_seconds peak_rss_mb cpu_seconds".
timing() { tail -n 1 "$1" | awk '{ printf "%.2f %.0f %.2f", $1, $2 / 1024, $3 + $4 }'; }
# A `key value` line of the PETSc driver's output → value(s).
key() { awk -v k="$2" '$1 == k { $1 = ""; sub(/^ /, ""); print; exit }' "$1"; }
# max |u − u_exact| over the vertices of a result: /mesh/vertices and /fields/u read with
# h5dump (17 digits), the exact u of ball.toml.
max_error() {
    h5dump -y -w 0 -m '%.17g' -o "$1.vertices.txt" -d /mesh/vertices "$1" > /dev/null &&
    h5dump -y -w 0 -m '%.17g' -o "$1.u.txt" -d /fields/u "$1" > /dev/null &&
    awk 'function exact(x, y,   r) {
             r = sqrt(x * x + y * y)
             return r <= 0.697965148223374 ? sqrt(1 - r * r) : -0.680259411891719 * log(r) + 0.471519893402112
         }
         { gsub(/,/, " ") }
         FNR == NR { for (i = 1; i <= NF; i++) xy[nxy++] = $i; next }
         { for (i = 1; i <= NF; i++) { e = $i - exact(xy[2 * nu], xy[2 * nu + 1]); nu++
                                       if (e < 0) e = -e; if (e > m) m = e } }
         END { if (nu == 0 || 2 * nu != nxy) exit 1; printf "%.6e\n", m }' \
        "$1.vertices.txt" "$1.u.txt"
    local status=$?
    rm -f "$1.vertices.txt" "$1.u.txt"
    return $status
}

for n in "$@"; do
    k=0 cells=$(( (n - 1) / 4 ))
    while [ $cells -gt 1 ] && [ $(( cells % 2 )) -eq 0 ]; do cells=$(( cells / 2 )); k=$(( k + 1 )); done
    if [ $(( (n - 1) % 4 )) -ne 0 ] || [ $cells -ne 1 ]; then
        echo "peers-bench: N = $n is not 4 · 2^K + 1 (PETSc refines a 5 × 5 grid K times)" >&2
        exit 2
    fi
    vertices=$(( n * n ))

    # PETSc: 5 × 5, K refinements with a solve on each grid.
    base=$out/petsc-$n
    echo "peers-bench: PETSc, $n × $n (5 × 5 grid, -snes_grid_sequence $k)" >&2
    if /usr/bin/time -f "%e %M %U %S" -o "$base.time" "$ball" -da_grid_x 5 -da_grid_y 5 \
            -snes_grid_sequence $k -snes_type vinewtonrsls -pc_type mg > "$base.log" 2>&1 &&
        [ "$(key "$base.log" grid)" = "$n $n" ]; then
        read -r wall rss cpus <<< "$(timing "$base.time")"
        echo "petsc,$vertices,$cpus" >> "$cpu"
        echo "petsc,$vertices,$wall,$(key "$base.log" max_error),$(key "$base.log" finest_iterations),$rss" >> "$csv"
        echo "petsc $n levels $(key "$base.log" level_iterations) total $(key "$base.log" iterations)" >> "$notes"
    else
        read -r wall rss cpus <<< "$(timing "$base.time")"
        echo "petsc,$vertices,$wall,,,$rss" >> "$csv"
        echo "petsc $n failed $(tail -n 1 "$base.log")" >> "$notes"
    fi

    # Ours: the same vertices, the 4 × 4-cell rectangle refined K times, multigrid.
    base=$out/obstacle-$n
    echo "peers-bench: obstacle, $n × $n (mesh.n = 4, mesh.refine = $k, multigrid)" >&2
    if /usr/bin/time -f "%e %M %U %S" -o "$base.time" "$bin" solve "$scene" --set mesh.refine=$k \
            --set mesh.memory_limit_gb="$memory_gb" --quiet --out "$base.h5" > "$base.log" 2>&1 &&
        error=$(max_error "$base.h5"); then
        read -r wall rss cpus <<< "$(timing "$base.time")"
        its=$("$bin" info "$base.h5" | awk -F' = ' '$1 == "  iterations" { print $2; exit }')
        echo "obstacle,$vertices,$wall,$error,$its,$rss" >> "$csv"
        echo "obstacle,$vertices,$cpus" >> "$cpu"
        # Newton steps per level (/solver newton_steps_level_L), coarsest first.
        steps=$(for l in $(seq 0 "$k"); do
            h5dump -a "/solver/newton_steps_level_$l" "$base.h5" | awk '/\(0\)/ { print $2 }'
        done | tr '\n' ' ')
        echo "obstacle $n levels $steps" >> "$notes"
    else
        read -r wall rss cpus <<< "$(timing "$base.time")"
        echo "obstacle,$vertices,$wall,,,$rss" >> "$csv"
        echo "obstacle $n failed $(grep -m 1 -i 'error' "$base.log" || tail -n 1 "$base.log")" >> "$notes"
    fi
done

# The Markdown: one row per size, both codes and the ratio ours/PETSc.
awk -F, -v notes="$notes" -v cpufile="$cpu" -v memgb="$memory_gb" -v load="load average $load_start at the start, $(cut -d' ' -f1-3 /proc/loadavg) at the end ($(nproc) cores)" '
    BEGIN { while ((getline line < notes) > 0) { split(line, w, " "); note[w[1] "," w[2]] = substr(line, length(w[1] w[2]) + 3) }
            while ((getline line < cpufile) > 0) { split(line, w, ","); cpu[w[1], w[2]] = w[3] } }
    NR == 1 { next }
    { v = $2; if (!(v in seen)) { seen[v] = 1; order[n++] = v }
      for (i = 3; i <= 6; i++) val[$1, v, i] = $i }
    # A run without an error failed: its wall time and RSS are no measure, no ratio.
    function ok(code, v) { return val[code, v, 4] != "" }
    function ratio(v, i) { return ok("obstacle", v) && ok("petsc", v) && val["petsc", v, i] > 0 ? sprintf("%.2f×", val["obstacle", v, i] / val["petsc", v, i]) : "–" }
    function cell(code, v, i) { return !ok(code, v) ? (i == 3 ? "failed" : "–") : val[code, v, i] }
    function wall(code, v) { return cell(code, v, 3) ((code, v) in cpu ? " (" cpu[code, v] ")" : "") }
    END {
        print "# Ball obstacle: PETSc SNESVI (mg, grid sequencing) and obstacle (Newton multigrid, grid sequencing)"
        print ""
        print "Whole-process wall time (s; in parentheses its CPU time, user + system), max |u − u_exact| over the vertices, Newton iterations on the finest level, peak RSS (MB); ratio = ours / PETSc; " load "; our memory guard'"'"'s limit " memgb " GB."
        print ""
        print "| vertices | PETSc wall (CPU) | ours wall (CPU) | ratio | PETSc max error | ours max error | ratio | PETSc its | ours its | PETSc RSS | ours RSS | ratio |"
        print "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
        for (j = 0; j < n; j++) {
            v = order[j]; side = sqrt(v)
            printf "| %d (%d²) | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n", v, side,
                wall("petsc", v), wall("obstacle", v), ratio(v, 3), cell("petsc", v, 4), cell("obstacle", v, 4), ratio(v, 4),
                cell("petsc", v, 5), cell("obstacle", v, 5), cell("petsc", v, 6), cell("obstacle", v, 6), ratio(v, 6)
        }
        print ""
        print "Newton iterations per level (coarsest first: PETSc 5², ours 5² vertices) and in all; runs that failed:"
        print ""
        for (j = 0; j < n; j++) { side = sqrt(order[j])
            if (("petsc," side) in note) print "- PETSc " side "²: " note["petsc," side]
            if (("obstacle," side) in note) print "- obstacle " side "²: " note["obstacle," side] }
    }' "$csv" > "$md"
cat "$md"
