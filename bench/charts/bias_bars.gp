# Converged error of every mode per scene (the last round, P = spp), as bars on a log axis.
# gnuplot -e "dat='OUT/bias.dat'; out='docs/results/bias_converged'" bench/charts/bias_bars.gp
# dat: whitespace-separated, header "scene pt rp exact skip", one scene per row.
set style data histograms
set style histogram clustered gap 1
set style fill solid 0.8 border -1
set logscale y
set grid ytics lc rgb '#dddddd'
set key top left
set ylabel 'relative MSE at P (trimmed 1 %, reference noise subtracted)'
set title 'Converged error: pt vs rp vs exact (and skip), same P'
set xtics noenhanced
do for [t in 'png svg'] {
  if (t eq 'png') { set terminal pngcairo size 720,420 font 'DejaVu Sans,10'; set output out.'.png' }
  if (t eq 'svg') { set terminal svg size 720,420 font 'DejaVu Sans,10'; set output out.'.svg' }
  plot dat using 2:xtic(1) title columnheader(2) lc rgb '#000000', \
       '' using 3 title columnheader(3) lc rgb '#1f77b4', \
       '' using 4 title columnheader(4) lc rgb '#2ca02c', \
       '' using 5 title columnheader(5) lc rgb '#d62728'
  unset output
}
