from slam2d.cli import main

raise SystemExit(main())
