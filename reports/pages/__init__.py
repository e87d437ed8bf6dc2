"""The HTML pages: a run's report, the run index, the comparison, fleet, campaign and calibration
pages. Importing the package imports none of its modules."""
