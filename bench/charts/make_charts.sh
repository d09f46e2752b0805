#!/usr/bin/env bash
# Charts and image strips from a scripts/bench.sh output folder: error against CPU and wall time per
# scene (log-log, every mode and Cycles plain and adaptive; trimmed and full relative MSE; against the
# independent Cycles reference too when the run had one), bias (error against samples
# per pixel; converged error per mode), the equal-time strips (PNG), and the RESULTS.md tables (OUT/results_tables.md).
#   bash bench/charts/make_charts.sh OUT CHARTS
set -euo pipefail
OUT=$1 CHARTS=$2
HERE=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$CHARTS"
for part in main big; do
  csv=$OUT/$part/csv
  [ -d "$csv" ] || continue
  for f in "$csv"/*_pt.csv; do
    [ -f "$f" ] || continue
    tag=$(basename "$f" _pt.csv)
    gnuplot -e "csv='$csv'; tag='$tag'; xcol='cpu_s'; out='$CHARTS/error_cpu_$tag'; title='$tag: trimmed error against CPU time'" \
        "$HERE/error_time.gp"
    gnuplot -e "csv='$csv'; tag='$tag'; xcol='cpu_s'; ycol='rel_mse'; out='$CHARTS/error_cpu_full_$tag'; title='$tag: full error (fireflies included) against CPU time'" \
        "$HERE/error_time.gp"
    gnuplot -e "csv='$csv'; tag='$tag'; xcol='wall_s'; out='$CHARTS/error_wall_$tag'; title='$tag: trimmed error against wall time'" \
        "$HERE/error_time.gp"
    rm -f "$CHARTS/error_wall_$tag.svg"   # wall time says little on a shared machine: PNG only
    if [ "$(tail -1 "$f" | cut -d, -f15)" != nan ] && [ -n "$(tail -1 "$f" | cut -d, -f15)" ]; then   # Cycles reference
      gnuplot -e "csv='$csv'; tag='$tag'; xcol='cpu_s'; ycol='rel_mse_trim_cy'; out='$CHARTS/error_cpu_cyref_$tag'; title='$tag: trimmed error against the Cycles reference'" \
          "$HERE/error_time.gp"
      gnuplot -e "csv='$csv'; tag='$tag'; xcol='cpu_s'; ycol='rel_mse_cy'; out='$CHARTS/error_cpu_cyref_full_$tag'; title='$tag: full error against the Cycles reference'" \
          "$HERE/error_time.gp"
    fi
    if [ "$part" = main ]; then
      gnuplot -e "csv='$csv'; tag='$tag'; out='$CHARTS/bias_$tag'" "$HERE/error_spp.gp"
      gnuplot -e "csv='$csv'; tag='$tag'; ycol='rel_mse'; out='$CHARTS/bias_full_$tag'" "$HERE/error_spp.gp"
      if [ -f "$OUT/$part/strip/${tag}_skip.exr" ] && [ -f "$OUT/$part/strip/${tag}_rp.exr" ]; then
        /usr/bin/python3 "$HERE/strip.py" "$OUT/$part/strip/$tag" "$CHARTS/strip_$tag.png"
      fi
    fi
  done
done
# Converged error per scene and mode (last row of each run's CSV).
dat=$OUT/main/bias.dat
echo "scene pt rp exact skip" > "$dat"
for f in "$OUT"/main/csv/*_pt.csv; do
  tag=$(basename "$f" _pt.csv)
  row=${tag%_*}
  for m in pt rp exact skip; do
    c=$OUT/main/csv/${tag}_$m.csv
    v=NaN
    [ -f "$c" ] && v=$(tail -1 "$c" | cut -d, -f8)
    row="$row $v"
  done
  echo "$row" >> "$dat"
done
if compgen -G "$OUT/main/csv/*_rp.csv" >/dev/null; then   # the bars need rp and exact runs
  gnuplot -e "dat='$dat'; out='$CHARTS/bias_converged'" "$HERE/bias_bars.gp"
fi
/usr/bin/python3 "$HERE/tables.py" "$OUT" > "$OUT/results_tables.md"
echo "tables: $OUT/results_tables.md"
ls -la "$CHARTS"
