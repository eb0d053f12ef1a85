from fgins.entry import main

raise SystemExit(main())
