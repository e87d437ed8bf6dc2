"""The asyncio host driver: the link, moves, waits and arrival, paths. Importing the package
imports none of its modules."""
