import sys

from testbed.campaign_cli import main

if __name__ == "__main__":  # a spawned campaign worker process imports the main module: it must not run it
    sys.exit(main())
