"""Counting a model's factorisations in tests (a wrapper on its factoriser)."""


def counting_factorisations(model) -> dict:
    """Wrap ``model``'s factoriser so that each factorisation adds 1 to the
    returned ``{"n": ...}``."""
    count = {"n": 0}
    plain = model.factorizer.factor

    def factor(H, shift=0.0):
        count["n"] += 1
        return plain(H, shift)
    model.factorizer.factor = factor
    return count
