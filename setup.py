"""The compiled kernel of small maps: everything else is in pyproject.toml.

The extension is optional: without a C compiler the install goes on and the filter
uses its numpy code throughout (``ekfviz.filters.ekf.HAVE_KERNEL`` is then False).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "ekfviz.filters._kernel",
            ["ekfviz/filters/_kernel.c"],
            extra_compile_args=["-O2", "-std=c99", "-Wall", "-Wextra", "-Wno-unused-parameter"],
            optional=True,
        )
    ]
)
