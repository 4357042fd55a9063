"""Packaging: the checkout's top-level folders become one installed package, ``depthmocap``.

``shared/``, ``train/``, ``runtime/`` and ``bench/`` stay at the top of the checkout and are
installed as ``depthmocap.shared`` and so on; ``configs/`` and ``models/`` go in as package data
(``depthmocap/configs``, ``depthmocap/models``) so the shipped forest and presets are found
without a checkout (``shared/resources.py``). pyproject.toml cannot prefix discovered package
names, hence this file; everything else is declared there.
"""

from setuptools import find_packages, setup

CODE = ("shared", "train", "runtime", "bench")
DATA = {
    "configs": ["*.yaml", "*.json"],
    "models": ["*.npz", "*.yaml", "*.json", "README.md"],
}

code_packages = find_packages(include=[f"{c}" for c in CODE] + [f"{c}.*" for c in CODE])
setup(
    packages=["depthmocap"]
    + [f"depthmocap.{p}" for p in code_packages]
    + [f"depthmocap.{d}" for d in DATA],
    package_dir={
        "depthmocap": "depthmocap",
        **{f"depthmocap.{name}": name for name in (*CODE, *DATA)},
    },
    package_data={
        "depthmocap.shared": ["py.typed", "*.schema.json"],
        **{f"depthmocap.{d}": patterns for d, patterns in DATA.items()},
    },
)
