"""The external-command adapter's spec (the adapter: external.py)."""

from strings_bench.methods.spec import MethodSpec

SPEC = MethodSpec(
    name="external", title="External", group="adapter",
    implementation="strings_bench.methods.external:ExternalCommandAdapter",
    description="run any training program (setting command) and evaluate the test-view renders it writes")
