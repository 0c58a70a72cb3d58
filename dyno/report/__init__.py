"""``report.html`` for a run: :mod:`dyno.report.html` builds the page (pure), :mod:`dyno.report.writer`
reads the run directory and writes it, :mod:`dyno.report.figures` draws the SVG figures."""
