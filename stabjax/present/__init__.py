"""Presentation: how a result is shown, whatever its kind.

* the kit: :mod:`.kit` (the result opener, its kind, the system behind it, outcome names and colours, where
  discovered attractors lie) and :mod:`.labels` (every word on a figure, page or table);
* :mod:`.show`: ``plot(result, out)`` draws any result, ``summary(ds)`` is the text the command line prints;
* the figures of each kind: :mod:`.maps` (verdict maps), :mod:`.basins` (named outcomes, basin fractions,
  discovered attractors), :mod:`.refinement` (boundary refinements);
* :mod:`.report` (one HTML page), :mod:`.viewmodel` and :mod:`.view` (the browser explorer: its result model
  and its Bokeh page), :mod:`.shock` (minimal fatal shocks). Which result a written figure or page shows is
  stamped into it by :func:`stabjax.run.outputs.stamp_output`.

Nothing heavy is imported with these modules: matplotlib, Bokeh, xarray and JAX are imported where used.
"""
