# Error against time, log-log, every mode of one scene (and Cycles when scored).
# gnuplot -e "csv='OUT/csv'; tag='cornell_128x128'; xcol='cpu_s'; out='docs/results/error_cpu_cornell_128x128'; title='...'" bench/charts/error_time.gp
# Writes out.png and out.svg. y: ycol, default rel_mse_trim (relative MSE without the 1 % largest pixel terms,
# the reference's own noise subtracted); rel_mse is the full one; the *_cy columns score against the
# independent Cycles reference instead of eprfarm's.
if (!exists("xcol")) xcol = 'cpu_s'
if (!exists("title")) title = tag
if (!exists("ycol")) ycol = 'rel_mse_trim'
xlabel = (xcol eq 'cpu_s') ? 'CPU seconds (process, all threads)' : 'wall seconds'
set datafile separator ','
set logscale xy
set grid xtics ytics mxtics mytics lc rgb '#dddddd'
set key top right
set xlabel xlabel
cy = ycol[strlen(ycol)-2:] eq 'cy'
set ylabel (strstrt(ycol, '_trim') == 0 ? 'relative MSE (all pixels' : 'relative MSE (trimmed 1 %').(cy ? ', Cycles reference' : '').', its noise subtracted)'
set title title noenhanced
modes = 'pt rp skip exact cycles cycles_adaptive'
file(m) = sprintf('%s/%s_%s.csv', csv, tag, m)
exists_file(f) = system(sprintf('test -s %s && echo 1 || echo 0', f)) + 0
color(m) = m eq 'pt' ? '#000000' : m eq 'rp' ? '#1f77b4' : m eq 'skip' ? '#d62728' : m eq 'exact' ? '#2ca02c' : m eq 'cycles' ? '#ff7f0e' : '#9467bd'
present = ''
do for [i=1:words(modes)] { if (exists_file(file(word(modes,i)))) { present = present.' '.word(modes,i) } }
do for [t in 'png svg'] {
  if (t eq 'png') { set terminal pngcairo size 720,480 font 'DejaVu Sans,10'; set output out.'.png' }
  if (t eq 'svg') { set terminal svg size 720,480 font 'DejaVu Sans,10'; set output out.'.svg' }
  plot for [i=1:words(present)] file(word(present,i)) \
       using (column(xcol)):(column(ycol) > 0 ? column(ycol) : 1/0) \
       with linespoints pt 7 ps 0.35 pi (word(present,i)[1:6] eq 'cycles' ? 1 : 8) lw 1.5 lc rgb color(word(present,i)) title word(present,i) noenhanced
  unset output
}
