from teamslam.cli import main

raise SystemExit(main())
