"""dyno: CVT dynamometer acquisition, control and belt-model analysis.

Layers (dependencies point one way, top to bottom):
protocol -> transports -> acquisition -> control -> analysis/model -> ui/cli.
See docs/architecture.md.
"""

__version__ = "0.1.0"
