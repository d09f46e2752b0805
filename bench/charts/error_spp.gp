# Bias: error against samples per pixel (M + M'), log-log, pt / rp / exact / skip of one scene. An
# unbiased estimator keeps falling with the slope of pt; a biased one levels off at its bias.
# gnuplot -e "csv='OUT/csv'; tag='cornell_128x128'; [ycol='rel_mse';] out='docs/results/bias_cornell_128x128'" bench/charts/error_spp.gp
if (!exists("ycol")) ycol = 'rel_mse_trim'
set datafile separator ','
set logscale xy
set grid xtics ytics mxtics mytics lc rgb '#dddddd'
set key bottom left
set xlabel 'samples per pixel (mean M + M'')'
set ylabel (ycol eq 'rel_mse' ? 'relative MSE (all pixels' : 'relative MSE (trimmed 1 %').', reference noise subtracted)'
set title tag.': error against samples per pixel, '.(ycol eq 'rel_mse' ? 'full' : 'trimmed').' relative MSE' noenhanced
modes = 'pt rp exact skip'
file(m) = sprintf('%s/%s_%s.csv', csv, tag, m)
exists_file(f) = system(sprintf('test -s %s && echo 1 || echo 0', f)) + 0
color(m) = m eq 'pt' ? '#000000' : m eq 'rp' ? '#1f77b4' : m eq 'skip' ? '#d62728' : m eq 'exact' ? '#2ca02c' : '#ff7f0e'
present = ''
do for [i=1:words(modes)] { if (exists_file(file(word(modes,i)))) { present = present.' '.word(modes,i) } }
do for [t in 'png svg'] {
  if (t eq 'png') { set terminal pngcairo size 720,480 font 'DejaVu Sans,10'; set output out.'.png' }
  if (t eq 'svg') { set terminal svg size 720,480 font 'DejaVu Sans,10'; set output out.'.svg' }
  plot for [i=1:words(present)] file(word(present,i)) \
       using (column('mean_spp')):(column(ycol) > 0 ? column(ycol) : 1/0) \
       with lines lw 1.5 lc rgb color(word(present,i)) title word(present,i)
  unset output
}
