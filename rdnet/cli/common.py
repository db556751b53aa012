"""Arguments shared by subcommands (``--params``, ``--set``): kept for callers of this
module; the helpers live in :mod:`rdnet.config` (usable below the CLI layer)."""
from rdnet.config import add_params_args, cli_params_path, load_cli_params, params_source

__all__ = ["add_params_args", "cli_params_path", "load_cli_params", "params_source"]
