"""Builds the wheel's ahead-of-time kernels (see src/surfnorm/_aot.py); everything else is in pyproject.toml.

SURFNORM_AOT=0 builds a wheel without them (every kernel then compiles on its first call); SURFNORM_AOT=1 makes
a failure to build them an error instead of a warning. Editable installs (pip install -e) never build them.
"""

import os
import subprocess
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.dist import Distribution


class BuildPyAot(build_py):
    def run(self):
        super().run()
        want = os.environ.get("SURFNORM_AOT", "")
        if getattr(self, "editable_mode", False) or want == "0":
            return
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [self.build_lib, os.environ.get("PYTHONPATH")])))
        package = Path(self.build_lib, "surfnorm").resolve()
        print(f"building surfnorm's ahead-of-time kernels into {package} (a few minutes)", flush=True)
        done = subprocess.run([sys.executable, "-m", "surfnorm._aot_build", str(package)], env=env)
        if done.returncode != 0:
            if want == "1":
                raise SystemExit("surfnorm: building the ahead-of-time kernels failed (SURFNORM_AOT=1)")
            print(
                "warning: surfnorm's ahead-of-time kernels were not built; the kernels compile on first use",
                file=sys.stderr,
            )


class PlatformDistribution(Distribution):
    """The wheel holds compiled code for one platform (tagged as such even where no AOT module was built)."""

    def has_ext_modules(self):
        return True


setup(cmdclass={"build_py": BuildPyAot}, distclass=PlatformDistribution)
