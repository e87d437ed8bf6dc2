"""The files a finished run hands to people and CI: report.html, junit.xml and the Markdown
summary. Importing the package imports none of its modules."""
