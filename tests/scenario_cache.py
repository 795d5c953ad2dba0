"""Each scenario of benchmarks/scenarios.py diagnosed once per test module (with a fixed seed)."""
from benchmarks.scenarios import make
from skigen.diagnose import diagnose


def diagnosis_cache(tmp_path_factory, seed: int):
    """get(name) → {"scenario", "data"}: the scenario's recording diagnosed on first use, without
    figures or C; a diagnosis that fails fails every test of it, once."""
    cache = {}

    def get(name):
        if name not in cache:
            sc = make(name, seed=seed)
            d = tmp_path_factory.mktemp(name)
            try:
                rep = diagnose(sc.model_file, sc.write_csv(d / f"{name}.csv"), d / "out", show_progress=False,
                               figures=False, emit=False)
                cache[name] = dict(scenario=sc, data=rep.data)
            except Exception as exc:
                cache[name] = exc
        if isinstance(cache[name], Exception):
            raise cache[name]
        return cache[name]
    return get
