"""The benchmark's subset and split names and its default route counts (:mod:`curbside.evaluate.subsets`
says what each is). They live in this module, which imports nothing, so that ``localize --help`` can
offer them without importing the simulator.
"""

SUBSETS: tuple[str, ...] = ("paper6", "downtown", "open")
SPLITS: tuple[str, ...] = ("test", "tune")
#: Routes per subset by default (``paper6`` always has six).
DEFAULT_ROUTES: dict[str, int] = {"paper6": 6, "downtown": 8, "open": 6}
