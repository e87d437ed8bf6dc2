"""``python -m armbench`` is the ``armbench`` command."""

from armbench.cli.main import program

if __name__ == "__main__":  # not when a worker process imports it (bench/workers/)
    program()
