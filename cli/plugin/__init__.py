"""The armbench pytest plugin: bench tests in plain pytest, into a run record. Importing the
package imports none of its modules."""
