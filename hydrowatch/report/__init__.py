"""HTML reports and plots (matplotlib, Agg) of training runs, accuracy measurements and the demo."""

from hydrowatch.report.html import Section, write_html

__all__ = ["Section", "write_html"]
