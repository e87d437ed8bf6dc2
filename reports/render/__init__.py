"""What every page renders with: formats, views, plots, the scorecard, the summary tables and
trends. Importing the package imports none of its modules."""
