"""CLI command modules. Each module defines ``register(app, catalog_app)`` and adds its commands.

Only ``mixcount.cli`` maps errors to exit codes; commands raise :class:`mixcount.errors.MixcountError`.
"""
