from rdnet.cli import entry

entry()
