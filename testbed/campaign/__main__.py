import sys

from testbed.campaign.cli_commands import main

sys.exit(main())
