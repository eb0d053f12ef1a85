from fgins.cli import main

raise SystemExit(main())
