"""armbench bench package."""

if __name__ != "armbench.bench":  # the checkout's folder imported by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.bench: import it by that name")

