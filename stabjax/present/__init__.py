"""Presentation: labels, maps and basin plots, the HTML report and the browser explorer."""
